"""The phrases of the request grammar (:mod:`vla_gr.training.request_grammar`): verbs,
politeness, questions, context sentences, relation and place words, negations and the joins
of two goals it builds requests from. Data only; nothing here reads a request set written to
measure the reader.
"""

from __future__ import annotations

from vla_gr.agent.reading.vocabulary import _words

VERBS = (
    "find", "go to", "take me to", "bring me to", "navigate to", "head to", "head over to",
    "walk to", "walk over to", "move to", "drive to", "get to", "get me to", "locate",
    "look for", "search for", "show me", "lead me to", "guide me to", "approach", "visit",
    "go find", "go over to", "make your way to", "travel to", "roll over to", "seek out",
    "track down", "get over to", "proceed to", "steer to", "go and find", "come to",
    "park yourself at", "meet me at", "wait at", "stop at", "be at", "go stand by",
    "park next to", "wait by", "pull up to", "go sit at", "station yourself at",
)  # fmt: skip
#: Clauses about what the user does there (any verb): no field in them.
DOING = (
    "i think it's {w}", "time to {w} around", "i want to {w} it", "it needs {w}",
    "i'm going to {w}", "we should {w} it", "something about {w}", "it's {w} again",
    "i left the {w} there", "the {w} is there", "i need to {w}", "while i {w}",
    "it looks {w}", "it seems {w}", "it's so {w}", "it is {w} now", "looks {w} to me",
    "the one i mean", "i think", "the one i want", "you know the one",
)  # fmt: skip
#: Context that names some other object (no goal): "let's watch a movie", "grab my keys".
OBJECT_CONTEXT = (
    "let's watch a {o}", "i left my {o} there", "grab the {o} on the way", "my {o} is broken",
    "i want to use the {o}", "bring the {o}", "i need my {o}", "i dropped a {o} near it",
    "the {o} is somewhere there", "i was looking at the {o}", "mind the {o}",
    "i want to sit at the {o}", "i'm by the {o}",
)  # fmt: skip
POLITE_BEFORE = (
    "please", "pls", "hey robot,", "robot,", "ok,", "okay so", "hi,", "could you", "can you",
    "would you", "would you please", "can you please", "i need you to", "now", "alright,",
    "hello, could you", "excuse me, can you", "robot:", "hey, can you", "quick,",
)  # fmt: skip
POLITE_AFTER = (
    "please", "pls", "thanks", "thank you", "now", "asap", "if you can", "for me",
    "when you can", "thx", "right away", "cheers", "quickly", "and stop there",
    "and stop", "and wait there", "and stay there",
)  # fmt: skip
FRONTED_COMMANDS = (
    "go there", "go there and stop", "take me there", "go", "find it", "go to it",
    "head there", "that one", "please", "pls", "drive there", "move there", "get there",
    "stop next to it", "that's where i want to go", "can you get there?", "go now",
)  # fmt: skip
WISHES = (
    "i want to go to", "i'd like to go to", "i need to get to", "i need", "i want",
    "i'm looking for", "i am looking for", "i would like to go to", "i wanna go to",
    "i have to get to", "i must get to", "we need to go to", "let's go to",
)  # fmt: skip
QUESTIONS = (
    ("where is", "?"), ("where's", "?"), ("can you find", "?"), ("could you find", "?"),
    ("do you see", "?"), ("can you take me to", "?"), ("could you bring me to", "?"),
    ("will you go to", "?"), ("can we go to", "?"), ("is there", "you can take me to?"),
    ("where can i find", "?"), ("could you lead me to", "?"), ("any chance you can find", "?"),
)  # fmt: skip
#: Sentences around a request that ask for nothing themselves (category words in them are
#: no goal: "I want to watch tv" does not send the robot to the tv).
CONTEXT = (
    "i'm tired.", "i want to sit down.", "my back hurts.", "i need a rest.", "it's late.",
    "i dropped my keys.", "i lost my phone somewhere.", "i'm cold.", "i feel sick.",
    "we have guests coming.", "i need to water the plants.", "the tv is too loud.",
    "i want to watch tv.", "i just woke up.", "i'm back from work.", "time for a nap.",
    "my feet hurt.", "i can't see well.", "the light is off.", "it's so hot in here.",
    "let's get moving.", "quick question.", "one more thing.", "ok listen.",
    "i need to use the bathroom.", "dinner is ready soon.", "i left my glasses somewhere.",
    "the game starts soon.", "i want to read.", "mom is waiting.", "i need a break.",
    "after lunch i want to relax.", "good morning.", "hello robot.", "thanks for earlier.",
)  # fmt: skip
CHAT = (
    "hello", "hi there", "what time is it?", "how are you?", "thanks", "thank you so much",
    "never mind", "stop", "wait", "what can you do?", "good night", "are you there?",
    "tell me a joke", "who are you?", "ok", "cancel that", "nothing, sorry", "bye",
    "what's the weather like?", "i'm hungry", "turn on the lights", "play some music",
)  # fmt: skip
NEAR = (
    "next to", "near", "beside", "by", "close to", "right next to", "right by", "alongside",
    "adjacent to", "near to", "just by", "at", "nearby", "against", "by the side of",
)  # fmt: skip
ROOM_PREP = ("in", "in the", "inside the", "in my", "in our", "within the", "over in the")
#: How a place that is no room of the house is said ("on the balcony", "out in the yard").
PLACE_PREP = ROOM_PREP + ("on the", "out on the", "out in the", "down in the",
                            "up in the", "on my")  # fmt: skip
#: WordNet roots of the places no room table holds: other rooms, outbuildings, floors,
#: porches, balconies, patios, gardens, yards.
OTHER_PLACES = ("room.n.01", "outbuilding.n.01", "floor.n.02", "area.n.05", "porch.n.01",
                 "balcony.n.01", "garden.n.01", "yard.n.02")  # fmt: skip
DETERMINERS = ("the", "the", "the", "a", "my", "that", "our", "this", "")
SIZE = ("big", "small", "little", "large", "old", "new", "comfy", "wooden", "tall", "round")
#: Shapes that say the anchor before the goal, or refer back to it ("beside it").
ANCHOR_FIRST = (
    "next to the {a} there's a {n}", "near the {a} is the {n}", "by the {a} , the {n}",
    "somewhere near the {a} is a {n} ;", "the {a} has a {n} next to it",
    "{a} - the {n} next to it", "the {n} with the {a} next to it", "the {n} , {a} next to it",
    "the {n} that has a {a} beside it", "there's a {a} and a {n} beside it",
    "the {n} with a {a} by it", "i'm at the {a} - the {n} beside it",
)  # fmt: skip
NEGATIONS = (
    ("the {n} that isn't {c}", "c"), ("the {n} that is not {c}", "c"),
    ("not the {c} {n}", "c"), ("any {n} except the {c} one", "c"),
    ("a {n} but not the {c} one", "c"), ("the {n} which isn't {c}", "c"),
    ("any {n} other than the {c} one", "c"), ("the {n} not in the {r}", "r"),
    ("the {n} that's not in the {r}", "r"), ("a {n} outside the {r}", "r"),
    ("the {n} that isn't next to the {a}", "a"), ("the {n} not near the {a}", "a"),
    ("a {n} without the {a} next to it", "a"), ("no, not the {c} {n}", "c"),
    ("the {n}, but not in the {r}", "r"), ("any {n} apart from the {c} one", "c"),
    ("the {n} that is never {c}", "c"), ("the {n} that's not {c}", "c"),
    ("anything but the {n}", "n"), ("anything except the {c} {n}", "c"),
    ("any {n} but the {c} one", "c"), ("everything except the {n}", "n"),
    ("not the {n} in the {r}", "r"), ("a {n} , just not the {c} one", "c"),
)  # fmt: skip
NEGATION_WORDS = _words(
    "anything everything just isn't not except but other than outside without no apart from never"
)
#: Two goals joined by "and" alone: "the bed and the toilet", "the sofa as well as the tv".
AND = ("and", "and the", "and also", "and also the", "as well as", "plus", "and a", ", and",
        "and my", "& the", "and then the")  # fmt: skip
SECOND = (
    "and then", "then", "and after that", ", then", ". then", "and then go to", "after that",
    ", and then", "and next", ", next", "and also", "and", ", after that", "and later",
    ". then go to", ". after that, find", ". next, go to", ". then find", ". now", ". and",
    ". afterwards, go to", "; then", ". after that go to", "followed by", ", followed by",
    "and afterwards",
)  # fmt: skip
#: Two goals asked for together: "both the bed and the sofa", "... - go to each".
BOTH = ("both", "both the", "visit both", "go to both", "check both", "i need both",
         "find both", "take me to both", "see both", "i want both", "go see both")  # fmt: skip
BOTH_AND = ("and", "and the", "and also", "as well as", "plus", "&", "and also the")
EACH = ("- go to each", ", each of them", "one after the other", "in that order", ", both",
         "go to each", "visit each", "both please", "- both of them", ", one then the other",
         "in any order", "each one", ", all two")  # fmt: skip
#: A stop on the way to another goal: "stop by the plant on your way to the toilet".
ON_THE_WAY = (
    ("stop by", "on your way to"), ("swing by", "on the way to"), ("pass by", "before going to"),
    ("visit", "before you go to"), ("check", "on your way over to"), ("drop by", "then go on to"),
    ("stop at", "on the way to"), ("pop by", "en route to"), ("go past", "and end up at"),
    ("call at", "before heading to"), ("swing past", "and then carry on to"),
)  # fmt: skip
#: One goal after another, the first said in a clause: "after the bed, go to the toilet".
AFTER = (
    ("after", ", go to"), ("after the visit to", ", head to"), ("once you've been to", ", find"),
    ("when you're done at", ", go to"), ("start at", "and finish at"), ("first", ", then"),
    ("begin with", ", then go to"), ("after you reach", "go on to"), ("once at", ", move to"),
    ("when you get to", ", continue to"), ("from", "go on to"), ("once you find", ", find"),
)  # fmt: skip
GIBBERISH_LETTERS = "abcdefghijklmnopqrstuvwxyz"
#: How a request is turned into its opposite before its verb: "don't go to ...".
DO_NOT = (
    "don't", "do not", "dont", "never", "please don't", "please do not", "no need to",
    "you don't need to", "you don't have to", "there's no need to", "i don't want you to",
    "i don't need you to", "you shouldn't", "you should not", "don't bother to",
    "do not ever", "no, don't", "we don't need to", "stop trying to", "try not to",
    "i told you not to", "you mustn't", "let's not", "i'd rather you didn't",
)  # fmt: skip
#: Verbs that say to keep away from, or to leave out, what follows them.
KEEP_AWAY = (
    "stay away from", "keep away from", "keep clear of", "steer clear of", "avoid",
    "don't bother with", "forget about", "never mind", "skip", "ignore", "keep off",
    "don't touch", "don't go near", "do not go near", "don't come near", "don't bump into",
    "don't knock over", "stay out of the way of", "leave alone", "don't block",
)  # fmt: skip
#: How often a class is said by its name (-1) or by a word 0, 1, 2, 3+ levels below its senses.
DEPTH_SHARE = {-1: 0.45, 0: 0.25, 1: 0.18, 2: 0.08, 3: 0.04}
