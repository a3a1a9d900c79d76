"""The k-fold networks kept in the repository (``benchmarks/fold-networks``): each file is the one its
``SHA256SUMS`` names, each network was trained without the sequences of its fold, and each folder holds the
recipe its README says (the first network of ``epo``'s pair reads the flow's spread, the second the centred flow)."""

from pathlib import Path

import pytest
import torch

from eponet.weights import sha256_of
from tests.benchmarks import load_benchmark

REPO = Path(__file__).resolve().parents[1]
ROOT = REPO / "benchmarks" / "fold-networks"
PAIR = ROOT / "epo-v5-pair"
# the model options of each network of the pair, by its place in a fold folder
RECIPES = {"weights.pt": {"flow_spread": 9, "flow_centring": "none"},
           "seed1/weights.pt": {"flow_spread": 0, "flow_centring": "rigid"}}


def listed(folder: Path) -> dict[str, str]:
    """``SHA256SUMS`` of ``folder`` as relative path -> digest, read as ``kfold.py`` reads it."""
    sums = load_benchmark("kfold").listed_sha256(folder)
    return {str(path.relative_to(folder.resolve())): digest for path, digest in sums.items()}


def checkpoint(path: Path) -> dict:
    return torch.load(path, map_location="cpu", weights_only=True)


def held_out(state: dict) -> list[str]:
    """The sequences a network's training recipe excluded (its fold)."""
    return state["meta"]["spec"]["phases"][0]["data"]["davis"]["exclude"]


def test_every_network_is_listed_with_its_sha256():
    sums = listed(PAIR)
    on_disk = {str(p.relative_to(PAIR)) for p in PAIR.rglob("*") if p.is_file() and p.suffix in (".pt", ".json")}
    assert set(sums) == on_disk
    for name, digest in sums.items():
        assert sha256_of(PAIR / name) == digest, name


def test_each_fold_network_was_trained_without_its_fold_and_with_its_recipe():
    folds = {}
    for fold in sorted(PAIR.glob("fold*")):
        i = int(fold.name.removeprefix("fold"))
        for place, options in RECIPES.items():
            if not (fold / place).is_file():
                continue
            state = checkpoint(fold / place)
            config = state["config"]
            assert {k: config.get(k, 0) for k in options} == options, (fold / place)
            spec = state["meta"]["spec"]
            excluded = held_out(state)
            assert len(excluded) == 6 and spec["validation"]["davis"]["sequences"] == excluded
            assert spec["geometry"]["stages"]["rigidity"]["prior_groups"] == 4
            assert spec["seed"] == 0 and len(state["meta"]["history"]) == 8
            assert folds.setdefault(i, excluded) == excluded  # both networks of a fold hold out the same six
    assert folds, "no fold networks found"
    names = [n for six in folds.values() for n in six]
    assert len(names) == len(set(names))  # the folds are disjoint


def test_the_folds_are_the_kfold_protocols(shared_data):
    kfold = load_benchmark("kfold")
    names = (shared_data / "davis2016-train" / "DAVIS" / "ImageSets" / "train.txt").read_text().split()
    split = kfold.folds(names)
    for fold in sorted(PAIR.glob("fold*")):
        i = int(fold.name.removeprefix("fold"))
        for place in RECIPES:
            if (fold / place).is_file():
                assert held_out(checkpoint(fold / place)) == split[i], (fold / place)


@pytest.mark.parametrize("place", sorted(RECIPES))
def test_a_fold_network_loads_as_the_motion_net_stage_loads_it(place):
    from eponet.plugins.motion_net.epo_unet import load_unet

    path = next(iter(sorted(PAIR.glob(f"fold*/{place}"))))
    digest = listed(PAIR)[str(path.relative_to(PAIR))]
    model, loaded = load_unet(str(path), sha256=digest)
    assert loaded == digest
    assert {k: model.config[k] for k in RECIPES[place]} == RECIPES[place]
    assert model(torch.zeros(1, model.input_channels, 48, 64)).shape == (1, 1, 48, 64)


def test_kfold_reads_the_sums_it_checks_the_kept_networks_with(tmp_path):
    kfold = load_benchmark("kfold")
    assert kfold.listed_sha256(tmp_path) == {}  # networks trained here carry no list
    (tmp_path / "fold0").mkdir()
    (tmp_path / "SHA256SUMS").write_text("ab" * 32 + "  fold0/weights.pt\n" + "cd" * 32 + " *fold0/seed1/weights.pt\n")
    assert kfold.listed_sha256(tmp_path) == {(tmp_path / "fold0" / "weights.pt").resolve(): "ab" * 32,
                                             (tmp_path / "fold0" / "seed1" / "weights.pt").resolve(): "cd" * 32}
    kept = kfold.listed_sha256(PAIR)
    assert len(kept) == len((PAIR / "SHA256SUMS").read_text().splitlines()) and all(p.is_file() for p in kept)
