"""A small vocabulary of marine concepts, each a set of ImageNet-1k classes, and the query parser that uses it.

The packaged EfficientNet-Lite0 has no text tower, so an operator's query is answered through the concept words it
contains: "underwater image with fish" asks for the probability mass of every ImageNet fish class, and "underwater
image without fish" for the rest of the mass. Keeping the vocabulary here, as plain data, lets the docs table, the
refusal message and the tests all read the same source.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from companion.errors import MerlionError

# ImageNet-1k class index -> name, only the classes the vocabulary uses (names as torchvision lists them).
IMAGENET_CLASSES: dict[int, str] = {
    0: "tench", 1: "goldfish", 2: "great white shark", 3: "tiger shark", 4: "hammerhead", 5: "electric ray",
    6: "stingray", 33: "loggerhead", 34: "leatherback turtle", 35: "mud turtle", 36: "terrapin", 37: "box turtle",
    107: "jellyfish", 108: "sea anemone", 109: "brain coral", 112: "conch", 115: "sea slug", 116: "chiton",
    117: "chambered nautilus", 118: "Dungeness crab", 119: "rock crab", 120: "fiddler crab", 121: "king crab",
    122: "American lobster", 123: "spiny lobster", 124: "crayfish", 125: "hermit crab", 147: "grey whale", 148: "killer whale",
    149: "dugong", 150: "sea lion", 327: "starfish", 328: "sea urchin", 329: "sea cucumber", 389: "barracouta",
    390: "eel", 391: "coho", 392: "rock beauty", 393: "anemone fish", 394: "sturgeon", 395: "gar",
    396: "lionfish", 397: "puffer", 801: "snorkel", 833: "submarine", 913: "wreck", 973: "coral reef",
    983: "scuba diver",
}

_FISH = (0, 1, 2, 3, 4, 5, 6, 389, 390, 391, 392, 393, 394, 395, 396, 397)


@dataclass(frozen=True)
class Concept:
    name: str
    words: tuple[str, ...]
    """Words and phrases (lower case, singular and plural) that name the concept in a query."""
    classes: tuple[int, ...]
    """ImageNet-1k class indices whose probability mass is the concept's."""


CONCEPTS: tuple[Concept, ...] = (
    Concept("fish", ("fish", "fishes", "anemone fish", "anemonefish", "clownfish", "lionfish", "pufferfish",
                     "puffer", "barracuda", "sturgeon"), _FISH),
    Concept("shark", ("shark", "sharks"), (2, 3, 4)),
    Concept("ray", ("ray", "rays", "stingray", "stingrays", "manta", "mantas"), (5, 6)),
    Concept("eel", ("eel", "eels", "moray", "morays"), (390,)),
    Concept("turtle", ("turtle", "turtles", "sea turtle", "sea turtles", "terrapin", "terrapins"),
            (33, 34, 35, 36, 37)),
    Concept("jellyfish", ("jellyfish", "jellyfishes", "jelly", "jellies", "medusa", "medusae"), (107,)),
    Concept("coral", ("coral", "corals", "coral reef", "coral reefs", "reef", "reefs"), (109, 973)),
    Concept("starfish", ("starfish", "starfishes", "sea star", "sea stars"), (327,)),
    Concept("sea urchin", ("sea urchin", "sea urchins", "urchin", "urchins"), (328,)),
    Concept("sea cucumber", ("sea cucumber", "sea cucumbers", "holothurian", "holothurians"), (329,)),
    Concept("crab", ("crab", "crabs"), (118, 119, 120, 121, 125)),
    Concept("lobster", ("lobster", "lobsters", "crayfish"), (122, 123, 124)),
    Concept("sea anemone", ("sea anemone", "sea anemones", "anemone", "anemones"), (108,)),
    Concept("sea slug", ("sea slug", "sea slugs", "nudibranch", "nudibranchs"), (115,)),
    Concept("mollusc", ("mollusc", "molluscs", "mollusk", "mollusks", "shell", "shells", "conch", "chiton",
                        "chitons", "nautilus"), (112, 116, 117)),
    Concept("whale", ("whale", "whales", "orca", "orcas"), (147, 148)),
    Concept("marine mammal", ("marine mammal", "marine mammals", "dugong", "dugongs", "manatee", "manatees",
                              "sea lion", "sea lions", "seal", "seals"), (147, 148, 149, 150)),
    Concept("diver", ("diver", "divers", "scuba", "snorkeler", "snorkelers", "snorkel", "swimmer", "swimmers"),
            (801, 983)),
    Concept("wreck", ("wreck", "wrecks", "shipwreck", "shipwrecks"), (913,)),
    Concept("submarine", ("submarine", "submarines", "submersible", "submersibles"), (833,)),
)

NEGATIONS = ("without", "no", "not", "none", "absent", "lacking", "free of", "empty of", "devoid of")

_TOKEN = re.compile(r"[a-z]+")


def known_concepts() -> str:
    """The concept names, comma separated, for refusal messages."""
    return ", ".join(c.name for c in CONCEPTS)


@dataclass(frozen=True)
class ParsedQuery:
    text: str
    concepts: tuple[Concept, ...]
    negated: bool

    @property
    def classes(self) -> tuple[int, ...]:
        return tuple(sorted({i for c in self.concepts for i in c.classes}))


def _phrases() -> list[tuple[tuple[str, ...], Concept]]:
    """Every naming phrase as a word tuple, longest first, so "sea urchin" wins over "urchin"."""
    out = [(tuple(w.split()), c) for c in CONCEPTS for w in c.words]
    return sorted(out, key=lambda item: -len(item[0]))


_PHRASES = _phrases()
_NEGATION_PHRASES = sorted((tuple(n.split()) for n in NEGATIONS), key=len, reverse=True)


def parse_query(text: str) -> ParsedQuery:
    """The concepts a query names and whether they are negated ("without fish", "no fish").

    A negation word negates every concept after it in the query ("no fish or sharks").

    Raises MerlionError (one line, listing the known concepts) when the query names none, or mixes negated and
    plain concepts (e.g. "fish without divers"), which a single probability mass cannot express.
    """
    words = _TOKEN.findall(text.lower())
    found: list[tuple[Concept, bool]] = []
    negate_next = False
    i = 0
    while i < len(words):
        neg = next((p for p in _NEGATION_PHRASES if tuple(words[i:i + len(p)]) == p), None)
        if neg is not None:
            negate_next = True
            i += len(neg)
            continue
        match = next(((p, c) for p, c in _PHRASES if tuple(words[i:i + len(p)]) == p), None)
        if match is not None:
            found.append((match[1], negate_next))
            i += len(match[0])
            continue
        i += 1
    if not found:
        raise MerlionError(f"query {text!r} names no concept the imagenet encoder knows; known concepts: "
                           f"{known_concepts()} (or use --encoder clip)")
    flags = {neg for _, neg in found}
    if len(flags) > 1:
        raise MerlionError(f"query {text!r} mixes wanted and negated concepts; the imagenet encoder scores one "
                           f"concept set per query: put the negated part in a --negative query")
    concepts = tuple(dict.fromkeys(c for c, _ in found))
    return ParsedQuery(text=text, concepts=concepts, negated=found[0][1])
