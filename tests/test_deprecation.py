"""`jtraj.deprecation.renamed_argument`: the old name's value with a warning, and both names
refused."""

import numpy as np
import pytest

from jtraj.deprecation import renamed_argument


def test_old_name_is_taken_with_a_warning():
    with pytest.warns(DeprecationWarning, match="layout= is deprecated: it is now called variables="):
        assert renamed_argument("compact", "paper", "variables", "layout", "compact") == "paper"


def test_new_name_alone_needs_no_warning(recwarn):
    assert renamed_argument("lean", None, "variables", "layout", "compact") == "lean"
    assert not [w for w in recwarn if issubclass(w.category, DeprecationWarning)]


@pytest.mark.parametrize("new_value", ["lean", np.arange(3.0), np.zeros(1), np.array(["compact"])])
def test_both_names_are_refused(new_value):
    # an array under the new name is not taken for the default: its == is elementwise, and
    # its truth value (ambiguous for more than one entry) must not decide
    with pytest.raises(TypeError, match="got both variables= and layout="):
        renamed_argument(new_value, "paper", "variables", "layout", "compact")


def test_array_default_given_again_is_the_default():
    default = np.arange(3.0)
    with pytest.warns(DeprecationWarning):
        assert renamed_argument(default, "paper", "variables", "layout", default) == "paper"
