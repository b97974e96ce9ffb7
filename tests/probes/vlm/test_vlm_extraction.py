"""Answer extraction on hand-written replies: the strict rule (the paper's: a letter alone or at the end) and the
lenient one (strict, else the one option whose text the reply contains), and the letter mapping of rotated
prompts (circular evaluation)."""

from __future__ import annotations

import pytest

from newtphys.vqa_scoring import extract_letter, extract_letter_lenient
from probes.vlm.prompting import rotate, to_prompt_letter, to_set_letter

MASS = ("0.25 kg", "0.50 kg", "1 kg", "10 kg")


@pytest.mark.parametrize(
    ("reply", "strict", "lenient"),
    [
        ("B", "B", "B"),
        ("b.", "B", "B"),
        ("The answer is (C)", "C", "C"),
        ("It weighs 0.50 kg.", None, "B"),  # option text, punctuation ignored
        ("10 kg", None, "D"),  # "1 kg" is not a whole-word match inside "10 kg"
        ("The answer: 1 kg!", None, "C"),
        ("I think it is 10 kg, not sure", None, "D"),
        ("about 0.5 kg", None, None),  # not an option's text
        ("either 1 kg or 10 kg", None, None),  # two unrelated options
        ("B. 0.50 kg", None, "B"),  # a leading letter is not the strict rule; the option text is
        ("I cannot tell", None, None),
    ],
)
def test_strict_and_lenient_extraction_of_hand_written_replies(reply: str, strict: str | None, lenient: str | None):
    assert extract_letter(reply) == strict
    assert extract_letter_lenient(reply, MASS) == lenient


def test_lenient_prefers_the_longer_option_that_contains_another():
    options = ("red ball", "ball", "blue ball", "cube")
    assert extract_letter_lenient("It is the red ball.", options) == "A"  # "ball" yields to "red ball"
    assert extract_letter_lenient("the ball", options) == "B"
    assert extract_letter_lenient("Image 3", ("image 2", "image 3", "image 4", "image 5")) == "B"
    with pytest.raises(ValueError, match="4 options"):
        extract_letter_lenient("x", ("a", "b"))


def test_rotation_shows_set_option_k_plus_r_and_maps_letters_back():
    options = ("w", "x", "y", "z")
    assert rotate(options, 0) == options
    assert rotate(options, 1) == ("x", "y", "z", "w")
    assert rotate(options, 3) == ("z", "w", "x", "y")
    for r in range(4):
        shown = rotate(options, r)
        for k, letter in enumerate("ABCD"):
            # the prompt's letter k shows option shown[k], which is the set's option to_set_letter(letter, r)
            assert options["ABCD".index(to_set_letter(letter, r))] == shown[k]
            assert to_prompt_letter(to_set_letter(letter, r), r) == letter
    assert to_set_letter(None, 2) is None
