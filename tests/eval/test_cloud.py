"""Cloud scores with known answers: removed points, shifted points, per floor, file formats."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from mfmap.config import EvalConfig
from mfmap.errors import GroundTruthError
from mfmap.eval import evaluate
from mfmap.eval.io import read_cloud, read_ply, write_ply

SPACING_M = 0.5
ELEVATIONS = [0.0, 4.0]


def _lattice() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """8 x 8 x 4 points per floor, 0.5 m apart, two floors 4 m apart; also (i + j + k) per point."""
    i, j, k = np.meshgrid(np.arange(8), np.arange(8), np.arange(4), indexing="ij")
    ijk = np.stack([i.ravel(), j.ravel(), k.ravel()], axis=1)
    xyz = ijk * SPACING_M
    both = np.concatenate([xyz, xyz + np.array([0, 0, ELEVATIONS[1]])]).astype(np.float32)
    floor = np.repeat([0, 1], len(xyz))
    return both, floor, np.tile(ijk.sum(axis=1), 2)


def _floors(h: SimpleNamespace) -> dict[str, object]:
    return h.floors_doc(ELEVATIONS, {}, [])


def test_known_fraction_removed_gives_that_completeness(
    make_build: Callable[..., Path], h: SimpleNamespace, tmp_path: Path
) -> None:
    ref, floor, ijk_sum = _lattice()
    # Remove a quarter of floor 1: every removed point keeps a lattice neighbour 0.5 m away.
    keep = ~((floor == 1) & (ijk_sum % 4 == 0))
    assert (~keep).sum() == 64
    out = make_build(cloud=(ref[keep], floor[keep]), floors=_floors(h))
    ref_path = tmp_path / "ref.ply"
    write_ply(ref_path, ref)  # no floor field: assigned by z from the build's elevations
    m = evaluate(out, cloud=ref_path).metrics
    assert m["cloud.map_points"] == 448 and m["cloud.ref_points"] == 512
    assert m["cloud.floor0.ref_points"] == 256 and m["cloud.floor1.ref_points"] == 256
    for d in ("5cm", "10cm", "20cm"):
        assert m[f"cloud.recall_{d}"] == 448 / 512
        assert m[f"cloud.recall_miss_{d}"] == pytest.approx(64 / 512)
        assert m[f"cloud.precision_{d}"] == 1.0
        assert m[f"cloud.fscore_{d}"] == pytest.approx(2 * 0.875 / 1.875)
        assert m[f"cloud.floor0.recall_{d}"] == 1.0
        assert m[f"cloud.floor1.recall_{d}"] == 0.75
        assert m[f"cloud.floor1.fscore_{d}"] == pytest.approx(2 * 0.75 / 1.75)
    assert m["cloud.accuracy_m"] == 0.0
    assert m["cloud.completeness_m"] == pytest.approx(64 * SPACING_M / 512)
    assert m["cloud.floor1.completeness_m"] == pytest.approx(64 * SPACING_M / 256)
    assert m["cloud.floor0.completeness_m"] == 0.0
    assert m["cloud.completeness_median_m"] == 0.0


def test_shifted_map_gives_that_accuracy(
    make_build: Callable[..., Path], h: SimpleNamespace, tmp_path: Path
) -> None:
    ref, floor, _ = _lattice()
    out = make_build(cloud=(ref + np.array([0, 0, 0.03], dtype=np.float32), floor), floors=_floors(h))
    ref_path = tmp_path / "ref.ply"
    write_ply(ref_path, ref, floor)
    cfg = EvalConfig(fscore_thresholds_m=[0.025, 0.05])
    m = evaluate(out, cloud=ref_path, config=cfg).metrics
    assert m["cloud.accuracy_m"] == pytest.approx(0.03, abs=1e-6)
    assert m["cloud.accuracy_median_m"] == pytest.approx(0.03, abs=1e-6)
    assert m["cloud.completeness_m"] == pytest.approx(0.03, abs=1e-6)
    assert m["cloud.fscore_2p5cm"] == 0.0 and m["cloud.fscore_miss_2p5cm"] == 1.0
    assert m["cloud.fscore_5cm"] == 1.0
    assert m["cloud.floor1.precision_5cm"] == 1.0


def test_ply_and_pcd_readers(tmp_path: Path) -> None:
    import open3d as o3d

    ref, floor, _ = _lattice()
    ascii_ply = tmp_path / "a.ply"
    body = "\n".join(f"{x} {y} {z} {f}" for (x, y, z), f in zip(ref, floor, strict=True))
    ascii_ply.write_text(
        "ply\nformat ascii 1.0\ncomment hand written\nelement vertex 512\nproperty float x\n"
        "property float y\nproperty float z\nproperty int floor\nend_header\n" + body + "\n"
    )
    got = read_cloud(ascii_ply)
    assert got.floor is not None and got.floor.tolist() == floor.tolist()
    assert np.array_equal(got.xyz, ref)

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(ref.astype(np.float64)))
    for name in ("o.ply", "o.pcd"):
        o3d.io.write_point_cloud(str(tmp_path / name), pcd)
        got = read_cloud(tmp_path / name)
        assert got.floor is None and np.allclose(got.xyz, ref)

    binary = tmp_path / "b.ply"
    write_ply(binary, ref, floor)
    props = read_ply(binary)
    assert sorted(props) == ["floor", "x", "y", "z"] and props["floor"].dtype == np.int32

    big = tmp_path / "big.ply"
    rec = np.empty(len(ref), dtype=[("x", ">f4"), ("y", ">f4"), ("z", ">f4"), ("floor", ">i2")])
    rec["x"], rec["y"], rec["z"], rec["floor"] = ref[:, 0], ref[:, 1], ref[:, 2], floor
    header = "ply\nformat binary_big_endian 1.0\nelement vertex 512\nproperty float x\nproperty float y\n"
    header += "property float z\nproperty short floor\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n"
    big.write_bytes(header.encode() + rec.tobytes())
    got = read_cloud(big)
    assert np.array_equal(got.xyz, ref) and got.floor is not None and got.floor.tolist() == floor.tolist()

    truncated = tmp_path / "t.ply"
    truncated.write_bytes(binary.read_bytes()[:-96])
    with pytest.raises(GroundTruthError, match=r"t\.ply: truncated PLY: 506 of 512 vertices"):
        read_cloud(truncated)
    with pytest.raises(GroundTruthError, match=r"nope\.ply: file not found"):
        read_cloud(tmp_path / "nope.ply")
