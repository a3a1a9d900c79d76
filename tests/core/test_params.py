import pytest

from eponet.core.params import Param, validate_params

SCHEMA = (
    Param("iterations", "int", 5, "mean-field iterations", minimum=1),
    Param("sigma", "float", 1.0, "a width", minimum=0.0, maximum=10.0),
    Param("mode", "choice", "a", "a mode", choices=("a", "b")),
    Param("flag", "bool", False, "a switch"),
)


def test_defaults_filled_in():
    values, problems = validate_params({}, SCHEMA, "stages.x")
    assert problems == []
    assert values == {"iterations": 5, "sigma": 1.0, "mode": "a", "flag": False}


@pytest.mark.parametrize(
    "params, message",
    [
        ({"iterations": "five"}, 'stages.x.iterations: expected a positive integer, got "five"'),
        ({"iterations": 0}, "stages.x.iterations: expected a positive integer, got 0"),
        ({"iterations": True}, "stages.x.iterations: expected a positive integer, got true"),
        ({"sigma": 11}, "stages.x.sigma: expected a number in [0, 10], got 11"),
        ({"mode": "c"}, "stages.x.mode: expected one of 'a', 'b', got \"c\""),
        ({"flag": "yes"}, 'stages.x.flag: expected true or false, got "yes"'),
    ],
)
def test_bad_values_are_reported_with_their_path(params, message):
    _, problems = validate_params(params, SCHEMA, "stages.x")
    assert problems == [message]


def test_unknown_parameter_suggests_nearest():
    _, problems = validate_params({"iteration": 3}, SCHEMA, "stages.x")
    assert len(problems) == 1
    assert "stages.x.iteration: unknown parameter (did you mean 'iterations'?)" in problems[0]


def test_int_accepted_for_float_and_converted():
    values, problems = validate_params({"sigma": 2}, SCHEMA, "p")
    assert problems == [] and values["sigma"] == 2.0 and isinstance(values["sigma"], float)


def test_required_parameter_missing():
    schema = (Param("path", "path", None, "a folder", required=True),)
    _, problems = validate_params({}, schema, "stages.flow")
    assert problems == ["stages.flow.path: missing required parameter (a folder; a path)"]


def test_invalid_default_is_a_programming_error():
    with pytest.raises(ValueError):
        Param("n", "int", -1, "bad default", minimum=0)


def test_many_accepts_one_value_or_a_non_empty_list_of_them():
    schema = (Param("weights", "weights", "a", "networks", many=True),)
    for value in ("b", ["b"], ["b", "c"]):
        values, problems = validate_params({"weights": value}, schema, "s")
        assert problems == [] and values["weights"] == value
    for bad in ([], ["b", ""], ["b", 3], {"b": 1}):
        _, problems = validate_params({"weights": bad}, schema, "s")
        assert problems == [f"s.weights: expected a built-in weights name or a file or a list of them, got {bad!r}"]
    with pytest.raises(ValueError, match="many is for"):
        Param("n", "int", 1, "a count", many=True)


def test_an_unquoted_all_digit_string_is_reported_as_the_number_yaml_made_of_it(tmp_path):
    """An all-zero sha256 left unquoted is the YAML int 0: say so, and to quote it (it read "got 0")."""
    from eponet.core.errors import SpecError
    from eponet.core.spec import load_spec

    spec = tmp_path / "spec.yaml"
    spec.write_text(f"input: {{path: {tmp_path}}}\noutput: {{dir: {tmp_path / 'out'}}}\n"
                    f"stages: {{motion_net: {{weights: epo-davis, sha256: {'0' * 64}}}}}\n")
    with pytest.raises(SpecError) as caught:
        load_spec(spec)
    assert caught.value.problems == ["stages.motion_net.sha256: expected a string or a list of them or null, got the "
                                     "number 0 (YAML reads unquoted digits as a number; quote the value)"]
    _, problems = validate_params({"name": 12345}, (Param("name", "str", "a", "a name"),), "x")
    assert problems == ["x.name: expected a string, got the number 12345 (YAML reads unquoted digits as a number; "
                        "quote the value)"]
