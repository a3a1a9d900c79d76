"""The weights catalogue: a built-in name is verified, and a ``sha256`` given with it must be the catalogue's."""

import pytest

from eponet.core.errors import MissingWeights
from eponet.weights import builtin_weights, resolve_weights


@pytest.mark.parametrize("name", ["epo-davis", "epo-plus-davis"])
def test_a_sha256_given_with_a_builtin_name_is_checked_against_the_catalogue(name):
    entry = builtin_weights()[name]
    assert resolve_weights(name, sha256=entry.sha256.upper(), kind=entry.kind) == (entry.file, entry.sha256)
    wrong = "0" * 64
    with pytest.raises(MissingWeights) as caught:
        resolve_weights(name, sha256=wrong, kind=entry.kind)
    assert caught.value.key == "sha256"
    assert str(caught.value) == f"built-in weights {name!r}: expected sha256 {entry.sha256} (the catalogue's), given {wrong}"
