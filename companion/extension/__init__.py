"""MERLION as a BlueOS extension: the page BlueOS lists, the Cockpit widget and actions, and the process that runs
the companion and its surface page side by side inside the extension's container."""
