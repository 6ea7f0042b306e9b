"""What the request intent head (:mod:`vla_gr.agent.reading.intent`) learns from: requests
to go somewhere against sentences that ask for nothing.

Requests come from the request grammar. Sentences that ask for nothing come from real
English: WordNet's usage examples of its verbs ("the laughter died down", "Is your cat
spayed?"), statements, questions and remarks written by people, not templates. Four in five
of those that name something get a house object put in its place ("She retained the green
couch in the kitchen"), so that naming a goal is not what makes a request: the sentence's
frame is.
Examples that open with their own verb ("Cut the bread") are imperatives and left out.
Requests told the other way round ("don't go to the red chair") ask to go nowhere either.
"""

from __future__ import annotations

import functools

import numpy as np

from vla_gr.training.request_grammar import RequestGrammar

__all__ = ["intent_corpus", "remarks", "wordnet_statements"]

#: Words after which the next word is the head of a noun phrase a house object can replace.
_DETERMINERS = frozenset(("the", "a", "an", "my", "his", "her", "their", "this", "that", "our",
                          "your"))  # fmt: skip
#: Endings any sentence of the corpus gets, so that its punctuation tells nothing of its kind
#: ("PURPLE CHAIR!!" asks; "what a chair!" does not).
_ENDINGS = ("", "", "", ".", "!", "!!", "?", "...")
#: Grammar outcomes that still ask to go somewhere (the reader refuses them for other reasons).
_ASKING = (None, "unknown_object", "unknown_colour", "unknown_room", "unknown_anchor", "two_goals")


@functools.lru_cache(maxsize=1)
def wordnet_statements() -> tuple[str, ...]:
    """WordNet's usage examples of its verbs of three words or more, but those that open with
    the verb they illustrate (imperatives) and frame placeholders ("----s"), sorted."""
    from vla_gr.agent.reading.vocabulary import _wordnet

    out = set()
    for synset in _wordnet().all_synsets("v"):
        lemmas = {lemma.lower() for lemma in synset.lemma_names()}
        for example in synset.examples():
            words = example.split()
            if len(words) >= 3 and words[0].lower() not in lemmas and "--" not in example:
                out.add(example.strip())
    return tuple(sorted(out))


def _with_house_object(sentence: str, grammar: RequestGrammar, rng) -> str | None:
    """``sentence`` with one determiner's noun replaced by a described house object; None when
    it has no determiner followed by a word."""
    words = sentence.split()
    spots = [k for k in range(len(words) - 1) if words[k].lower() in _DETERMINERS]
    if not spots:
        return None
    k = spots[int(rng.integers(len(spots)))]
    return " ".join(words[:k] + [grammar.goal_description(rng)] + words[k + 2 :])


def remarks(grammar: RequestGrammar, count: int, seed: int) -> list[str]:
    """``count`` sentences that ask for nothing: WordNet statements, four in five of those
    that can naming a house object (drawn with replacement under ``seed``)."""
    rng = np.random.default_rng(seed)
    pool = wordnet_statements()
    out = []
    while len(out) < count:
        sentence = pool[int(rng.integers(len(pool)))]
        if rng.random() < 0.8:
            sentence = _with_house_object(sentence, grammar, rng) or sentence
        out.append(sentence)
    return out


def intent_corpus(grammar: RequestGrammar, count: int, seed: int) -> tuple[list[str], list[int]]:
    """(texts, labels) under ``seed``, shuffled. Asking to go somewhere (1): ``count`` grammar
    requests (but negations, which the tagger reads, and the grammar's chit-chat and gibberish,
    0), a quarter as many bare descriptions ("the green couch in the kitchen") and the requests
    among a fifth as many more, each beside a statement ("The tissue ossified. find the red
    chair"). Asking for
    nothing (0): ``count`` remarks (three in ten after an opener: "hey robot, ...") and a
    quarter as many requests told the other way round ("don't go to the red chair", "stay away
    from the sofa"; three in ten with a reason after them). Every sentence ends in a random
    punctuation mark or none."""
    rng = np.random.default_rng(seed + 3)
    texts, labels = [], []
    for request in grammar.batch(count, seed):
        if request.refuse == "negation":
            continue
        texts.append(request.text)
        labels.append(int(request.refuse in _ASKING))
    texts += [grammar.goal_description(rng) for _ in range(count // 4)]
    asking = [r.text for r in grammar.batch(count // 5, seed + 4) if r.refuse is None]
    for request, statement in zip(asking, remarks(grammar, len(asking), seed + 5)):
        link = (". ", ", ", " - ", "; ", " so ")[int(rng.integers(5))]
        first, second = (statement, request) if rng.random() < 0.6 else (request, statement)
        texts.append(first + link + second)
    labels += [1] * (len(texts) - len(labels))
    for remark in remarks(grammar, count, seed + 1):
        texts.append(f"{grammar.opener(rng)} {remark}" if rng.random() < 0.3 else remark)
    for command, reason in zip(
        (grammar.negated_command(rng) for _ in range(count // 4)),
        remarks(grammar, count // 4, seed + 6),
    ):
        texts.append(command + (", " + reason if rng.random() < 0.3 else ""))
    labels += [0] * (len(texts) - len(labels))
    texts = [_ending(text, rng) for text in texts]
    order = np.random.default_rng(seed + 2).permutation(len(texts))
    return [texts[k] for k in order], [labels[k] for k in order]


def _ending(text: str, rng) -> str:
    """``text`` without its final punctuation, and one of :data:`_ENDINGS` instead."""
    return text.rstrip(" .!?").rstrip() + _ENDINGS[int(rng.integers(len(_ENDINGS)))]
