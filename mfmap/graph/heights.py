"""Which heights place the floors: scale-true sensors first, the barometer calibrated on them.

A barometer says *which* floor and *when* very well, and *how high* poorly: its pressure-to-
height scale follows the air temperature (about 0.34 % per kelvin, 11 % between a 5 and a 35 deg
C building), and ventilation and the stack effect hold floors at pressures a few Pa to tens of
Pa off the hydrostatic ones (tens of centimetres to metres). Scale-true heights come from other
sensors in the same log: an elevator ride's from the IMU (mfmap.graph.ride: zero velocity at both
ends), a stair walk's from the lidar odometry.

Per transition from floor a to floor b the barometer measures, in the metres of the hypsometric
relation at the assumed temperature,

    d_baro = (z_b - z_a) / s + (o_b - o_a) + noise,

with s the height scale (1 at the assumed temperature) and o_f a per-floor pressure offset, as a
height. This module decides, before the factor graph is built, what the data support:

- `calibrate`: the scale from every transition measured both ways (a robust weighted mean, with
  a prior: the assumed temperature's honest uncertainty, or a Temperature topic's), and the
  spread of the per-floor offsets (the residuals' variance beyond the measurements' noise, with a
  weak prior). A scale no building's air allows (`scale_limits`) for every pair means the
  barometer does not measure this building's heights (a sealed enclosure, a wrong topic): it is
  then not used for heights at all.
- `decide`: which measurements of which transitions are used. A disagreement beyond the gate is
  settled by the others: of the measurements that could be left out, the one whose removal leaves
  the rest most consistent (chi-square over every floor pair, so other rides, walks and loops
  vote), with a penalty per source for how often it fails beyond its own sigma. The scale-true
  sensors have their own checks (the IMU's stand-stills and zero-velocity ends), the barometer
  has none, so when nothing else votes (one ride measured twice) the barometer gives way.

The graph (mfmap.graph.optimize) then carries the scale and the offsets as variables, with the
priors found here, and the accepted measurements as factors.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mfmap.types import F64, TransitionKind

# Air in a building from about -10 to +50 deg C at an assumed 295 K: heights scale by 0.89-1.10.
# A barometer whose every scale-true comparison falls outside (beyond its noise) is not
# measuring the air column between the floors.
SCALE_LIMITS = (0.85, 1.12)
# -2 log of how often a source is off by more than its sigma allows, once its own checks passed:
# the scale-true sensors alike, the barometer (steps at a ride, an offset beyond its prior) more
# often. Only a tie between two measurements and nothing else is settled by this alone.
_PENALTY = {"imu": 8.0, "lidar": 8.0, "barometer": 4.0}
# Cauchy width (in sigmas) of the scale's robust mean.
_CAUCHY_C = 3.0
# Transitions with less barometric height change than this say little about the scale.
_MIN_SCALE_BASE_M = 0.5


@dataclass(frozen=True)
class Measurement:
    """One sensor's height change across a transition (m) and its sigma."""

    source: str  # "imu" | "lidar" | "barometer"
    height_change_m: float
    sigma_m: float


@dataclass
class TransitionHeights:
    """What is known about one transition's height change, and what is used."""

    index: int
    kind: TransitionKind
    from_floor: int
    to_floor: int
    baro: Measurement | None  # in the barometer's metres (scale 1)
    scale_true: Measurement | None
    baro_reason: str = "ok"  # why there is no barometric height, when there is none
    scale_true_reason: str = "ok"
    use_baro: bool = False
    use_scale_true: bool = False
    why: str = ""

    @property
    def label(self) -> str:
        word = "ride" if self.kind == TransitionKind.ELEVATOR else "walk"
        return f"{word} {self.from_floor}->{self.to_floor}"


@dataclass
class Calibration:
    """The barometer's height scale and the spread of its per-floor offsets."""

    scale: float
    scale_sigma: float
    scale_prior: tuple[float, float]
    offset_sigma_m: float
    pairs: int  # transitions measured both ways that the estimate rests on
    usable: bool = True  # False: the barometer disagrees with every scale-true source
    warnings: list[str] = field(default_factory=list)

    def baro_sigma_m(self, item: TransitionHeights) -> float:
        """The honest sigma of a transition's barometric height after scaling: its own noise,
        the scale's uncertainty over its height, and the two floors' offsets."""
        assert item.baro is not None
        b = item.baro
        return math.sqrt((self.scale * b.sigma_m) ** 2 + (b.height_change_m * self.scale_sigma) ** 2
                         + 2.0 * self.offset_sigma_m**2)

    def to_json(self) -> dict[str, Any]:
        return {
            "scale": round(self.scale, 5),
            "scale_sigma": round(self.scale_sigma, 5),
            "scale_prior": [round(self.scale_prior[0], 5), round(self.scale_prior[1], 5)],
            "offset_sigma_m": round(self.offset_sigma_m, 4),
            "pairs": self.pairs,
            "barometer_heights_used": self.usable,
        }


def _both(items: list[TransitionHeights], used_only: bool) -> list[TransitionHeights]:
    return [
        it for it in items
        if it.baro is not None and it.scale_true is not None
        and abs(it.baro.height_change_m) >= _MIN_SCALE_BASE_M
        and (not used_only or (it.use_baro and it.use_scale_true))
    ]


def calibrate(
    items: list[TransitionHeights],
    scale_prior: tuple[float, float],
    offset_prior_sigma_m: float,
    offset_prior_weight: float = 1.0,
    scale_limits: tuple[float, float] = SCALE_LIMITS,
    used_only: bool = False,
) -> Calibration:
    """The scale and the offsets' spread from the transitions measured both ways.

    `scale_prior` (mean, sigma): 1 and the assumed temperature's uncertainty, or a Temperature
    topic's reading. `offset_prior_sigma_m` with the weight of `offset_prior_weight`
    transitions: the offsets' spread before the data. `used_only`: only transitions whose two
    measurements `decide` kept.
    """
    s0, sig_s0 = scale_prior
    pairs = _both(items, used_only)
    s, sig_s, sig_o = s0, sig_s0, offset_prior_sigma_m
    if not pairs:
        return Calibration(s, sig_s, scale_prior, sig_o, 0)
    t = np.array([p.scale_true.height_change_m for p in pairs if p.scale_true is not None])
    st = np.array([p.scale_true.sigma_m for p in pairs if p.scale_true is not None])
    b = np.array([p.baro.height_change_m for p in pairs if p.baro is not None])
    sb = np.array([p.baro.sigma_m for p in pairs if p.baro is not None])
    for _ in range(30):
        var = st**2 + (s * sb) ** 2 + 2.0 * sig_o**2
        r = (t - s * b) / np.sqrt(var)
        w = 1.0 / (1.0 + (r / _CAUCHY_C) ** 2)
        info = float(np.sum(w * b**2 / var)) + sig_s0**-2
        s_new = (float(np.sum(w * b * t / var)) + s0 * sig_s0**-2) / info
        # The offsets' variance: each pair's squared residual beyond its measurements' noise
        # holds two floors' offsets. Their median, so that one pressure step at a ride (an
        # outlier, not an offset) does not make every floor's offset look large.
        excess = np.maximum((t - s_new * b) ** 2 - st**2 - (s_new * sb) ** 2, 0.0) / 2.0
        n = excess.shape[0]
        sig_o_new = math.sqrt(
            (offset_prior_weight * offset_prior_sigma_m**2 + n * float(np.median(excess)))
            / (offset_prior_weight + n)
        )
        done = abs(s_new - s) < 1e-9 and abs(sig_o_new - sig_o) < 1e-9
        s, sig_s, sig_o = s_new, info**-0.5, sig_o_new
        if done:
            break
    cal = Calibration(s, sig_s, scale_prior, sig_o, len(pairs))
    _check_physics(cal, pairs, (t, st, b, sb), offset_prior_sigma_m, scale_limits)
    return cal


def _check_physics(
    cal: Calibration,
    pairs: list[TransitionHeights],
    measured: tuple[F64, F64, F64, F64],
    offset_prior_sigma_m: float,
    scale_limits: tuple[float, float],
) -> None:
    """Mark `cal` unusable, with a warning, when every pair's own scale is outside what a
    building's air allows, by more than three of its sigmas. `measured`: the pairs' scale-true
    heights and sigmas, then their barometric heights and sigmas."""
    t, st, b, sb = measured
    ratio = t / b
    ratio_sigma = np.sqrt(st**2 + (sb * ratio) ** 2 + 2.0 * offset_prior_sigma_m**2) / np.abs(b)
    lo, hi = scale_limits
    outside = np.abs(ratio - np.clip(ratio, lo, hi)) > 3.0 * ratio_sigma
    if np.all(outside):
        cal.usable = False
        listed = ", ".join(
            f"{p.label} {p.scale_true.height_change_m:+.2f} m ({p.scale_true.source}) against "
            f"{p.baro.height_change_m:+.2f} m" for p in pairs if p.scale_true is not None and p.baro is not None
        )
        cal.warnings.append(
            f"the barometer disagrees with every scale-true height beyond what the air in a "
            f"building allows (scale {lo:g}-{hi:g}; {listed}): the scale-true heights are used, the "
            "barometer's are not"
        )


def _solve(rows: list[tuple[int, int, float, float]], floors: list[int], start: int) -> tuple[dict[int, float], np.ndarray, np.ndarray]:
    """Least-squares floor heights from (from, to, change, sigma) rows, `start` at 0; returns
    the heights, the covariance of the free floors and the index of each floor in it."""
    free = [f for f in floors if f != start]
    col = {f: k for k, f in enumerate(free)}
    n = len(free)
    if n == 0:
        return {start: 0.0}, np.zeros((0, 0)), np.zeros(0)
    a = np.zeros((len(rows) + n, n))
    y = np.zeros(len(rows) + n)
    for k, (f0, f1, dz, sigma) in enumerate(rows):
        if f1 in col:
            a[k, col[f1]] += 1.0 / sigma
        if f0 in col:
            a[k, col[f0]] -= 1.0 / sigma
        y[k] = dz / sigma
    # A floor nothing connects stays solvable (at 0, with a huge sigma).
    a[len(rows):, :] = np.eye(n) * 1e-4
    cov = np.linalg.inv(a.T @ a)
    x = cov @ a.T @ y
    z = {start: 0.0, **{f: float(x[col[f]]) for f in free}}
    return z, cov, np.array([col.get(f, -1) for f in floors])


def _rows(items: list[TransitionHeights], cal: Calibration,
          skip: tuple[int, str] | None = None) -> list[tuple[int, int, float, float, int, str]]:
    out = []
    for it in items:
        if it.use_scale_true and it.scale_true is not None and skip != (it.index, "scale_true"):
            out.append((it.from_floor, it.to_floor, it.scale_true.height_change_m, it.scale_true.sigma_m,
                        it.index, "scale_true"))
        if it.use_baro and it.baro is not None and skip != (it.index, "baro"):
            out.append((it.from_floor, it.to_floor, cal.scale * it.baro.height_change_m,
                        cal.baro_sigma_m(it), it.index, "baro"))
    return out


def _chi2(rows: list[tuple[int, int, float, float, int, str]], floors: list[int], start: int) -> float:
    z, _, _ = _solve([r[:4] for r in rows], floors, start)
    return float(sum(((z[f1] - z[f0] - dz) / sigma) ** 2 for f0, f1, dz, sigma, _, _ in rows))


def _deletion_residual(rows: list[tuple[int, int, float, float, int, str]], k: int, floors: list[int],
                       start: int) -> float | None:
    """Row k against what the other rows predict for its floor pair, in sigmas (None when the
    others do not connect its two floors)."""
    f0, f1, dz, sigma, _, _ = rows[k]
    others = rows[:k] + rows[k + 1:]
    z, cov, index = _solve([r[:4] for r in others], floors, start)
    i0, i1 = index[floors.index(f0)], index[floors.index(f1)]
    g = np.zeros(cov.shape[0])
    if i1 >= 0:
        g[i1] += 1.0
    if i0 >= 0:
        g[i0] -= 1.0
    var = float(g @ cov @ g)
    if var > 1e4:  # connected only by the solver's placeholder
        return None
    return (dz - (z[f1] - z[f0])) / math.sqrt(sigma**2 + var)


def decide(items: list[TransitionHeights], cal: Calibration, start_floor: int, gate_sigma: float = 4.0) -> None:
    """Set each transition's `use_*` and `why` (see the module docstring)."""
    floors = sorted({start_floor} | {f for it in items for f in (it.from_floor, it.to_floor)})
    for it in items:
        it.use_scale_true = it.scale_true is not None
        it.use_baro = it.baro is not None and cal.usable
    rejected: dict[tuple[int, str], str] = {}
    while True:
        rows = _rows(items, cal)
        candidates = []
        for k in range(len(rows)):
            d = _deletion_residual(rows, k, floors, start_floor)
            if d is not None and abs(d) > gate_sigma:
                candidates.append((k, d))
        if not candidates:
            break
        scored = []
        for k, d in candidates:
            rest = rows[:k] + rows[k + 1:]
            source = _source(items, rows[k])
            scored.append((_chi2(rest, floors, start_floor) + _PENALTY[source], -abs(d), k, d))
        _, _, k, d = min(scored)
        f0, f1, _, _, index, which = rows[k]
        it = next(x for x in items if x.index == index)
        rejected[(index, which)] = f"differs from the other heights of floors {f0}/{f1} by {d:+.1f} sigma"
        if which == "baro":
            it.use_baro = False
        else:
            it.use_scale_true = False
    for it in items:
        it.why = _why(it, cal, rejected)


def _source(items: list[TransitionHeights], row: tuple[int, int, float, float, int, str]) -> str:
    it = next(x for x in items if x.index == row[4])
    m = it.baro if row[5] == "baro" else it.scale_true
    assert m is not None
    return m.source


def _why(it: TransitionHeights, cal: Calibration, rejected: dict[tuple[int, str], str]) -> str:
    parts = []
    st = it.scale_true
    if st is None:
        parts.append(f"no scale-true height ({it.scale_true_reason})")
    elif it.use_scale_true:
        parts.append(f"{st.source} {st.height_change_m:+.3f} +- {st.sigma_m:.3f} m")
    else:
        parts.append(f"{st.source} left out: {rejected.get((it.index, 'scale_true'), '')}")
    b = it.baro
    if b is None:
        parts.append(f"no barometric height ({it.baro_reason})")
    elif not cal.usable:
        parts.append("barometer left out: it disagrees with every scale-true height")
    elif it.use_baro:
        parts.append(f"barometer {cal.scale * b.height_change_m:+.3f} +- {cal.baro_sigma_m(it):.3f} m "
                     f"(scale {cal.scale:.4f})")
    else:
        parts.append(f"barometer left out: {rejected.get((it.index, 'baro'), '')}")
    return "; ".join(parts)
