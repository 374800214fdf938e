"""Input checks of `jtraj.nlp`: layouts, groups and bounds that cannot make an NLP are refused
with a message naming what is wrong (tiny problems: three knots, three variables each)."""

import pytest

from jtraj.nlp import Layout

LAYOUT = Layout((("x", 2), ("u", 1)))


def test_unknown_slot_names_the_layout():
    """Every look-up of an unknown slot says which slots there are; size() raised a bare KeyError('y')."""
    for lookup in (LAYOUT.size, LAYOUT.offset, LAYOUT.slice, lambda name: LAYOUT.columns([name])):
        with pytest.raises(KeyError, match=r"no slot 'y' in layout \['x', 'u'\]"):
            lookup("y")


@pytest.mark.parametrize(
    "slots, message",
    [
        # offset() found the first 'x' and size() the last one's size
        ((("x", 2), ("x", 3)), r"slot 'x' appears twice"),
        ((("x", -1),), r"slot 'x' has size -1; expected a whole number >= 0"),
        ((("x", 1.5),), r"slot 'x' has size 1.5"),
    ],
)
def test_layout_refuses_repeated_names_and_bad_sizes(slots, message):
    with pytest.raises(ValueError, match=message):
        Layout(slots)
