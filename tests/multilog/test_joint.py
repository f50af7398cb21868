"""The building graph's renaming of a log's variables: every factor kind keeps its error and
Jacobians on the new keys (GTSAM's own rekey for C++ factors, a wrapper for Python ones)."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from mfmap.graph.config import GraphConfig
from mfmap.graph.factors import SCALE, B, Builder, U, X, baro_height_factor
from mfmap.multilog.joint import LOG_STRIDE, _renamed, key_of


def _values(keys: list[int], own: list[int]) -> tuple[gtsam.Values, gtsam.Values]:
    """The same values on the building's keys and on the log's own."""
    renamed, local = gtsam.Values(), gtsam.Values()
    rng = np.random.default_rng(3)
    for new, old in zip(keys, own, strict=True):
        if chr(gtsam.Symbol(old).chr()) == "x":
            pose = gtsam.Pose3(gtsam.Rot3.Ypr(*rng.uniform(-0.3, 0.3, 3)), rng.uniform(-5, 5, 3))
            renamed.insert(new, pose)
            local.insert(old, pose)
        else:
            value = float(rng.uniform(0.9, 1.1))
            renamed.insert(new, value)
            local.insert(old, value)
    return renamed, local


def test_key_of_keeps_the_first_log_and_moves_the_others() -> None:
    assert key_of(0, X(7)) == X(7)
    moved = gtsam.Symbol(key_of(2, B(7)))
    assert chr(moved.chr()) == "b" and moved.index() == 7 + 2 * LOG_STRIDE


@pytest.mark.parametrize("same_floor", [False, True])
def test_a_python_height_factor_keeps_its_error_and_jacobians(same_floor: bool) -> None:
    factor = baro_height_factor(X(1), X(2), U(0), U(0 if same_floor else 1), 3.9, 0.05,
                                GraphConfig())
    own = list(factor.keys())
    keys = [key_of(1, k) for k in own]
    renamed, local = _values(keys, own)
    copy = _renamed(factor, keys)
    assert copy.error(renamed) == pytest.approx(factor.error(local), rel=1e-12)
    a = np.asarray(factor.linearize(local).jacobian()[0])
    b = np.asarray(copy.linearize(renamed).jacobian()[0])
    assert np.abs(a - b).max() < 1e-6 * max(1.0, np.abs(a).max())
    assert SCALE in own


def test_a_world_dz_factor_keeps_its_error() -> None:
    builder = Builder(GraphConfig())
    builder.world_dz("walk_z", X(1), X(2), 3.5, 0.02)
    factor = builder.entries[0].factor
    own = list(factor.keys())
    keys = [key_of(3, k) for k in own]
    renamed, local = _values(keys, own)
    assert _renamed(factor, keys).error(renamed) == pytest.approx(factor.error(local), rel=1e-12)
