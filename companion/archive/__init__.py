"""``merlion archive``: summarize a campaign of recorded dives on Ray, tagged from the dive logs, resumably."""
