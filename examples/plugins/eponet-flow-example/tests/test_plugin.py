"""The example plugin's tests: eponet's plugin test kit (``eponet.testing.check_stage``) asserts the flow protocol,
and one known answer checks the flow itself. Run with ``pytest`` in this folder once the package is installed
(``pip install -e .``)."""

import numpy as np
import pytest

from eponet.core.errors import SpecError
from eponet.core.types import Video
from eponet.testing import check_stage, sample_inputs
from eponet_flow_example.plugin import DisFineFlow, eponet_stages


def test_dis_fine_keeps_the_flow_protocol():
    """Shapes, dtypes, finite values, inputs left alone, determinism and one-line parameter errors, as installed."""
    report = check_stage("flow", "dis_fine")
    assert {"outputs", "determinism", "unknown parameter", "parameter types"} <= set(report.checks)


@pytest.mark.parametrize("params", [{"patch_size": 4}, {"patch_size": 32, "refinement_iterations": 0}])
def test_dis_fine_keeps_the_protocol_across_its_parameters(params):
    check_stage("flow", "dis_fine", **params)


def test_the_declaration_passes_before_the_package_is_installed():
    (spec,) = eponet_stages()
    assert check_stage("flow", spec).plugin == "dis_fine"


def test_a_bad_parameter_is_one_line_naming_it():
    with pytest.raises(SpecError, match=r"^stages\.flow\.patch_size: expected an integer in \[4, 32\], got 2$"):
        check_stage("flow", "dis_fine", patch_size=2)


def test_a_translation_gives_its_flow():
    """Known answer: the kit's frame shifted right by 2 px per frame has forward flow (2, 0) away from the border."""
    base = sample_inputs(shape=(96, 128)).video.frames[0]
    frames = np.stack([np.roll(base, 2 * t, axis=1) for t in range(3)])
    flow = DisFineFlow().estimate(Video("shifted", frames, ["0", "1", "2"], frames.shape[1:3]))
    inner = flow.forward[:, 16:-16, 16:-16]
    np.testing.assert_allclose(inner.reshape(-1, 2).mean(axis=0), [2.0, 0.0], atol=0.1)
    np.testing.assert_allclose(flow.backward[:, 16:-16, 16:-16].reshape(-1, 2).mean(axis=0), [-2.0, 0.0], atol=0.1)
