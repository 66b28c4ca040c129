"""How an operator's words become the ImageNet-1k classes the packaged encoder scores (its open vocabulary).

A query is cut into noun phrases at its joining words ("with", "or", "and", "of", ...), words that say nothing
about the content ("underwater image", "a", "some") are dropped, and each phrase is looked up in WordNet 3.0,
whose noun synsets ImageNet's classes are:

1. the longest run of words that is a WordNet noun, rightmost first ("sea cucumber", "scuba diver"); its
   classes are every ImageNet class at or below any of its senses (hyponyms): "crustacean" -> crabs, lobsters;
2. words before that noun are modifiers: they keep only the classes whose own or intermediate WordNet
   definitions name them ("reef fish" -> fish whose definition says reef, never the class "coral reef");
   a modifier that would keep nothing is left out, and a noun phrase that WordNet lists but under which no
   class lies ("marine animal") is read as its head noun ("animal") with its modifiers when it is a kind of it;
3. a noun with no class below it climbs its hypernyms (at most ``CLIMB`` steps) to the nearest everyday word
   that has some, else the nearest one that has some: "flatfish" -> "fish" (past the taxa "spiny-finned fish",
   "teleost fish", "bony fish"), "octopus" -> "cephalopod"; among those, classes whose name the word contains
   are preferred ("shipwreck" -> "wreck").

Each phrase is a term; a class's weight is the number of terms that reach it over the most any class gets, so
"fish or shark or ray or eel" weighs sharks, rays and eels fully and other fish at half, unlike "fish" alone.
A word WordNet does not know, or a phrase that reaches no class, refuses the query naming that word and
offering near WordNet nouns.
"""

from __future__ import annotations

import difflib
import functools
import re
from dataclasses import dataclass, replace

from companion.errors import MerlionError
from companion.vision.encoders.imagenet_synsets import class_of_offset, class_offsets
from companion.vision.encoders.wordnet_nouns import WordNetNouns, wordnet_nouns

NEGATIONS = ("without", "no", "not", "none", "absent", "lacking", "free of", "empty of", "devoid of")
JOINERS = frozenset("or and with of in on near at over under among by from to plus nor into onto inside "
                    "around beside behind between above below along across".split())
PLACES = frozenset("in on near at over under among by from into onto inside around beside behind between above "
                   "below along across".split())
"""Joining words after which a phrase says where the thing is, not what it is: "a crab on the sea floor"."""
CONTEXT_WEIGHT = 0.5
"""What a place phrase's classes weigh against the thing's: "fish near coral" is fish first, coral helping."""
FILLER = frozenset("""a an the some any many few several lots lot one two three four five plenty number numbers
    image images picture pictures photo photos photograph photographs frame frames scene scenes view views shot shots
    footage video videos clip clips underwater subsea undersea there is are being its their this that these those
    showing shows show shown containing contains contain seen visible just only small large big little tiny huge
    kind kinds type types sort sorts something thing things
    school schools shoal shoals group groups swarm swarms pod pods bunch colony colonies pair couple""".split())
CLIMB = 6
"""Hypernym steps a noun with no ImageNet class below it may climb to find its relatives ("wrasse" is 6 below
"fish": percoid, spiny-finned, teleost and bony fish lie between)."""
ANIMALS = 5
"""WordNet's lexicographer file of animals (noun.animal)."""
MIN_DEPTH = 6
"""How far below WordNet's root an ancestor must be to stand for a word it is climbed to from."""
MAX_RELATIVES = 40
"""More relatives than this is no longer a reading of the word ("rope" -> every artifact): refused instead."""
MAX_WORDS = 4
"""Longest WordNet lemma tried, in words ("portuguese man of war")."""
RELATED_STEPS = 3
"""WordNet links walked from a word the encoder cannot see to the relatives offered in its place."""
RELATED = 3
"""Relatives offered at most."""
_WORD = re.compile(r"[a-z][a-z'-]*|[,;/&+]")


class UnknownWord(MerlionError):
    """A query word that resolves to no ImageNet class; ``word``, ``brief`` and ``near`` make the short line."""

    def __init__(self, query: str, word: str, why: str, near: tuple[str, ...], brief: str,
                 related: bool = False) -> None:
        self.query = query
        self.word = word
        self.near = near
        """Spelling neighbours of a word WordNet does not know, or (``related``) the relatives it can see of one
        it does."""
        self.brief = brief
        label = "related words it can see" if related else "near words"
        hint = f"; {label}: {', '.join(near)}" if near else ""
        super().__init__(f"{word!r} {why} (query {query!r}){hint}")

    def short(self, width: int = 50, prefix: str = "") -> str:
        """A line for a STATUSTEXT: ``prefix``, the word and why first, then the near words that fit."""
        line = f"{prefix}{self.word!r} {self.brief}"
        shown = [n for i, n in enumerate(self.near) if len(line) + len(" (near: )") + len(", ".join(self.near[:i + 1]))
                 <= width]
        return (line + f" (near: {', '.join(shown)})" if shown else line)[:width]


@dataclass(frozen=True)
class Term:
    """One noun phrase of a query and the classes it reached."""

    phrase: str
    """The words as the query had them ("reef fish")."""
    noun: str
    """The WordNet noun it was read as ("fish")."""
    how: str
    """"noun", "narrowed by reef", "kind of animal, narrowed by marine" or "nearest: spiny-finned fish"."""
    classes: tuple[int, ...]
    names: tuple[str, ...]
    """Each class's name, in the order of ``classes``: kept with the term so that explaining a query read from
    the cache (``query_cache``) needs no WordNet."""
    context: bool = False
    """A place phrase ("on coral"): its classes weigh ``CONTEXT_WEIGHT``."""


@dataclass(frozen=True)
class ResolvedQuery:
    text: str
    terms: tuple[Term, ...]
    negated: bool
    left_out: tuple[str, ...] = ()
    """Place phrases that name nothing the encoder can see ("sea floor" in "a crab on the sea floor"): read, said
    by ``explain``, and left out rather than refusing the thing the query names."""

    @property
    def weights(self) -> dict[int, float]:
        """Class index -> weight in (0, 1]: the terms reaching it over the most terms any class is reached by."""
        counts: dict[int, float] = {}
        for term in self.terms:
            for c in term.classes:
                counts[c] = counts.get(c, 0.0) + (CONTEXT_WEIGHT if term.context else 1.0)
        top = max(counts.values(), default=1)
        return {c: n / top for c, n in sorted(counts.items())}

    @property
    def classes(self) -> tuple[int, ...]:
        return tuple(self.weights)

    def _names(self) -> dict[int, str]:
        return {c: n for t in self.terms for c, n in zip(t.classes, t.names, strict=True)}

    def explain(self) -> str:
        """One line per term: what it was read as and the classes it reached, by name."""
        lines = [f"query {self.text!r}{' (negated)' if self.negated else ''}:"]
        for t in self.terms:
            names = ", ".join(t.names)
            place = f", where it is: weighs {CONTEXT_WEIGHT:g}" if t.context else ""
            lines.append(f"  {t.phrase} -> {t.noun} [{t.how}{place}]: {len(t.classes)} classes: {names}")
        for phrase in self.left_out:
            lines.append(f"  {phrase}: where it is, but nothing the imagenet encoder can see: left out")
        return "\n".join(lines)

    def short(self, width: int = 50, prefix: str = "") -> str:
        """A line for a STATUSTEXT: ``{prefix}fish=16: tench,goldfish,...`` cut at ``width`` characters, the
        classes that weigh most first."""
        things = "+".join(t.phrase for t in self.terms if not t.context)
        head = f"{prefix}{'not ' if self.negated else ''}{things}={len(self.classes)}: "
        known = self._names()
        names = ",".join(known[c] for c in sorted(self.weights, key=lambda c: -self.weights[c]))
        line = head + names
        return line if len(line) <= width else line[: width - 2] + ".."


@functools.cache
def class_name(index: int) -> str:
    """The first WordNet lemma of an ImageNet class ("great white shark")."""
    return wordnet_nouns().synsets[class_offsets()[index]].name


def _term(phrase: str, noun: str, how: str, classes: set[int]) -> Term:
    ordered = tuple(sorted(classes))
    return Term(phrase, noun, how, ordered, tuple(class_name(c) for c in ordered))


def _classes_below(wn: WordNetNouns, offset: int) -> set[int]:
    index = class_of_offset()
    return {index[o] for o in wn.descendants(offset) if o in index}


def _chain_text(wn: WordNetNouns, index: int, stop: set[int]) -> str:
    """Lemmas and definitions of a class and of its ancestors up to (not including) the ``stop`` synsets."""
    out, stack, seen = [], [class_offsets()[index]], set()
    while stack:
        o = stack.pop()
        if o in seen or o in stop:
            continue
        seen.add(o)
        s = wn.synsets[o]
        out.append(" ".join(s.lemmas) + " " + s.gloss)
        stack.extend(s.hypernyms)
    return " ".join(out).lower()


def _narrow(wn: WordNetNouns, classes: set[int], heads: set[int], modifiers: list[str]) -> tuple[set[int], list[str]]:
    """Keep the classes whose own or intermediate definitions name every modifier that keeps any class."""
    used = []
    for mod in modifiers:
        forms = {mod, *wn.base_forms(mod)}
        pattern = re.compile(r"\b(?:" + "|".join(re.escape(f) for f in forms) + r")(?:s|es)?\b")
        kept = {c for c in classes if pattern.search(_chain_text(wn, c, heads))}
        if kept:
            classes, used = kept, [*used, mod]
    return classes, used


def _depth(wn: WordNetNouns, offset: int) -> int:
    """Steps from ``offset`` up to WordNet's root ("entity" is 0, "ship" 8)."""
    depth, level = 0, {offset}
    while all(wn.synsets[o].hypernyms for o in level):
        level = {h for o in level for h in wn.synsets[o].hypernyms}
        depth += 1
    return depth


def _climb(wn: WordNetNouns, phrase: str) -> tuple[set[int], str]:
    """The classes of the same kind (animal, artifact, ...) below a hypernym that has some, for a noun with none
    below it: the nearest hypernym within ``CLIMB`` steps that is an everyday word (``WordNetNouns.everyday``) or
    a class itself ("moray" -> "eel"), else the nearest.

    Taxa people never say stand between a word and the category it belongs to: "flatfish" is a spiny-finned
    fish, a teleost and a bony fish before it is a fish, and the four spiny-finned reef fish ImageNet has say
    less about a flatfish than "fish" does. Animal senses are tried first, those the word is the main name of
    first, then the others, most frequent first; an ancestor nearer the root than ``MIN_DEPTH`` ("material",
    "natural object") or with more than ``MAX_RELATIVES`` classes is too general to stand for the word."""
    offsets = class_offsets()
    # the camera is under water: animal senses first; then senses the word is the main name of ("seahorse" is
    # the fish's first name, and only the walrus's third)
    word = wn.base_forms(phrase)[0] if wn.base_forms(phrase) else phrase
    senses = sorted(wn.lookup(phrase), key=lambda s: (s.lexfile != ANIMALS, s.lemmas[0] != word))
    for sense in senses:
        frontier, hits = [sense.offset], []
        for _ in range(CLIMB):
            frontier = [h for o in frontier for h in wn.synsets[o].hypernyms if _depth(wn, h) >= MIN_DEPTH]
            found = [(o, {c for c in _classes_below(wn, o) if wn.synsets[offsets[c]].lexfile == sense.lexfile})
                     for o in frontier]
            hits += sorted(((o, f) for o, f in found if 0 < len(f) <= MAX_RELATIVES), key=lambda h: len(h[1]))
        if hits:
            offset, found = next((h for h in hits if wn.everyday(h[0]) or h[0] in class_of_offset()), hits[0])
            compact = phrase.replace(" ", "")
            named = {c for c in found if class_name(c).replace(" ", "") in compact}  # "shipwreck" -> "wreck"
            return (named or found), f"nearest: {wn.synsets[offset].name}"
    return set(), ""


def _is_kind_of(wn: WordNetNouns, phrase: str, head: str) -> bool:
    """Whether some sense of ``phrase`` lies below some sense of ``head`` ("marine animal" is an animal)."""
    heads = {s.offset for s in wn.lookup(head)}
    stack = [s.offset for s in wn.lookup(phrase)]
    seen: set[int] = set()
    while stack:
        o = stack.pop()
        if o in heads:
            return True
        if o not in seen:
            seen.add(o)
            stack.extend(wn.synsets[o].hypernyms)
    return False


def _resolve_phrase(wn: WordNetNouns, query: str, words: list[str]) -> Term:
    """A noun phrase (content words only) -> the term it names; UnknownWord if it names no class."""
    phrase = " ".join(words)
    unknown = next((w for w in words if not wn.is_english(w)), None)
    if unknown is not None:  # queries mean what they say: no word is skipped unread
        raise UnknownWord(query, unknown, "is not an English word that WordNet knows", _near(wn, unknown),
                          "unknown")
    whole_known = wn.knows(phrase) if len(words) > 1 else False
    for length in range(min(len(words), MAX_WORDS), 0, -1):
        for start in range(len(words) - length, -1, -1):  # rightmost first: the head noun ends a phrase
            span = " ".join(words[start:start + length])
            senses = wn.lookup(span)
            if not senses:
                continue
            if whole_known and span != phrase and not _is_kind_of(wn, phrase, span):
                continue  # "sea horse" is no horse
            found: set[int] = set()
            for s in senses:
                found |= _classes_below(wn, s.offset)
            if not found:
                continue
            modifiers = words[:start] + words[start + length:]
            how = "noun" if span == phrase else f"kind of {span}" if whole_known else "noun"
            if modifiers:
                found, used = _narrow(wn, found, {s.offset for s in senses}, modifiers)
                if used:
                    how = f"{how}, narrowed by {' '.join(used)}" if how != "noun" else f"narrowed by {' '.join(used)}"
            return _term(phrase, span, how, found)
    for length in range(min(len(words), MAX_WORDS), 0, -1):  # a noun with nothing below: its nearest relatives
        for start in range(len(words) - length, -1, -1):
            span = " ".join(words[start:start + length])
            if wn.knows(span):
                found, how = _climb(wn, span)
                if found:
                    return _term(phrase, span, how, found)
                raise UnknownWord(query, span, "names nothing the imagenet encoder can see", _related(wn, span),
                                  "not in model", related=True)
    raise UnknownWord(query, phrase, "is not a thing WordNet knows", _near(wn, words[-1]), "unknown")


def _near(wn: WordNetNouns, word: str) -> tuple[str, ...]:
    """WordNet nouns spelled like ``word`` that do reach a class, closest first (at most three): for a word
    WordNet does not know, most often a slip of the keyboard ("jellyfsh")."""
    near = difflib.get_close_matches(word, _seeable_lemmas(), n=3, cutoff=0.7)
    return tuple(n for n in near if n != word)


def _related(wn: WordNetNouns, word: str) -> tuple[str, ...]:
    """Words the encoder can see that WordNet links to a real word it cannot, nearest first (at most three).

    A real word needs relatives, not spelling neighbours ("sand" is not "sandal"): breadth-first over the
    part-whole links and the is-a links, one step up (no nearer the root than ``MIN_DEPTH``) and then only
    down, so relatives are the word's siblings and their kinds, not kinds of a far ancestor ("sponge" is an
    invertebrate, not any "animal"); at most ``RELATED_STEPS`` links away. A relative counts when it is an ImageNet class or an everyday word with at most
    ``MAX_RELATIVES`` classes below it; at equal distance, the word's own kind (animal, artifact, ...) first.
    "sand" -> sandbar, shore; "tire" -> car wheel; "kelp" has none (no alga is a class): no guess is offered."""
    index = class_of_offset()
    senses = sorted(wn.lookup(word), key=lambda s: s.lexfile != ANIMALS)
    seen = {s.offset for s in senses}
    level = [(s.offset, s.lexfile, True) for s in senses]  # (synset, the sense's kind, may climb)
    found: list[str] = []
    for _ in range(RELATED_STEPS):
        hits, after = [], []
        for offset, kind, climbing in level:
            s = wn.synsets[offset]
            up = [h for h in s.hypernyms if climbing and _depth(wn, h) >= MIN_DEPTH]
            for other in (*up, *s.hyponyms, *s.parts):
                if other in seen:
                    continue
                seen.add(other)
                below = len(_classes_below(wn, other))
                if 0 < below <= MAX_RELATIVES and (other in index or wn.everyday(other)):
                    hits.append((wn.synsets[other].lexfile != kind, wn.synsets[other].name))
                else:
                    after.append((other, kind, False))
        found += [name for _, name in sorted(hits, key=lambda h: h[0]) if name not in found and name != word]
        if len(found) >= RELATED:
            break
        level = after
    return tuple(found[:RELATED])


@functools.lru_cache(maxsize=1)
def _seeable_lemmas() -> tuple[str, ...]:
    """Every WordNet noun lemma with an ImageNet class at or below it (about 3,000 words: fast to search)."""
    wn = wordnet_nouns()
    index = class_of_offset()
    seeable: set[int] = set()
    for o in index:
        stack = [o]
        while stack:
            x = stack.pop()
            if x not in seeable:
                seeable.add(x)
                stack.extend(wn.synsets[x].hypernyms)
    return tuple(sorted({lemma for o in seeable for lemma in wn.synsets[o].lemmas}))


def _chunks(text: str) -> list[tuple[list[str], bool, bool]]:
    """The query's noun phrases (content words), whether a negation word came before each, and whether it says
    where the thing is (after a place word, ``PLACES``, once some thing was named: "a crab on the sea floor")."""
    tokens = _WORD.findall(text.lower())
    negations = sorted((tuple(n.split()) for n in NEGATIONS), key=len, reverse=True)
    out: list[tuple[list[str], bool, bool]] = []
    current: list[str] = []
    negate = place = False
    i = 0

    def close() -> None:
        if current:
            out.append((list(current), negate, place and any(not c for _, _, c in out)))
            current.clear()

    while i < len(tokens):
        neg = next((n for n in negations if tuple(tokens[i:i + len(n)]) == n), None)
        if neg is not None:
            close()
            negate = True
            i += len(neg)
            continue
        tok = tokens[i].strip("'-")
        i += 1
        if not tok or tok in JOINERS or not tok[0].isalpha():
            close()
            place = place or tok in PLACES
        elif tok not in FILLER:
            current.append(tok)
    close()
    return out


def resolve_query(text: str) -> ResolvedQuery:
    """The ImageNet classes a query names, term by term, and whether it is negated ("without fish").

    Raises MerlionError (one line) when a word resolves to nothing (naming it, with near words), when the query
    names nothing, or when it mixes negated and plain phrases ("fish without divers"), which one probability mass
    cannot express. A place phrase that names nothing the encoder can see is left out (``left_out``), not refused:
    the thing is still looked for; a word that is not English is refused wherever it stands.
    """
    chunks = _chunks(text)
    if not chunks:  # before WordNet is read: the pre-sampler's generic negative ends here at every start
        raise MerlionError(f"query {text!r} names nothing to look for: name a thing, e.g. 'fish' or 'crab' "
                           f"(or use --encoder clip)")
    wn = wordnet_nouns()
    terms: list[tuple[Term, bool]] = []
    left_out: list[str] = []
    for words, negated, place in chunks:
        try:
            term = _resolve_phrase(wn, text, words)
        except UnknownWord as err:
            if not place or err.brief != "not in model":
                raise
            left_out.append(" ".join(words))
            continue
        terms.append((replace(term, context=True) if place else term, negated))
    if len({negated for _, negated in terms}) > 1:
        raise MerlionError(f"query {text!r} mixes wanted and negated concepts; the imagenet encoder scores one "
                           f"concept set per query: put the negated part in a --negative query")
    return ResolvedQuery(text, tuple(dict.fromkeys(t for t, _ in terms)), terms[0][1], tuple(left_out))
