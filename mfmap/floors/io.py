"""Floors stage files: pressure CSVs in, floors.json out (its schema: docs/formats.md)."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import numpy as np

from mfmap.atomic import write_text_atomic
from mfmap.errors import LogError, OutputError
from mfmap.types import F64, FloorSegmentation, PressureSeries

# Median pressure magnitude -> factor to Pa. Indoor air pressure is 80-110 kPa.
_UNIT_BY_MAGNITUDE = ((20_000.0, 200_000.0, 1.0, "Pa"), (200.0, 2_000.0, 100.0, "hPa"), (20.0, 200.0, 1_000.0, "kPa"))


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def read_pressure_csv(path: Path) -> tuple[PressureSeries, list[str]]:
    """A CSV of time (s) and pressure (Pa, hPa or kPa, told apart by magnitude).

    Comma, semicolon or tab separated; lines starting with # or % are comments; an Android
    GetSensorData log (PRES lines, as in the IPIN competitions) is read too. The header is
    optional. With a header, time is the first column (or one named t/time/stamp) and pressure
    the column whose name says pressure (else the last); without one, the first and last
    columns. Returns the series and warnings (unit conversions, dropped rows).
    """
    try:
        text = path.read_text(errors="replace")
    except OSError as err:
        raise LogError(f"cannot read the pressure CSV ({err.__class__.__name__})", path) from err
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith(("#", "%"))]
    if any(ln.startswith("PRES;") for ln in lines):
        return _read_getsensordata(path, lines)
    first = lines[0] if lines else ""
    delimiter = ";" if ";" in first and "," not in first else "\t" if "\t" in first else ","
    rows = [r for r in csv.reader(lines, delimiter=delimiter) if r and any(c.strip() for c in r)]
    if not rows:
        raise LogError("the pressure CSV is empty", path)
    header: list[str] | None = None
    if not all(_is_number(c) for c in rows[0]):
        header = [c.strip().lower() for c in rows[0]]
        rows = rows[1:]
    width = len(header) if header is not None else len(rows[0]) if rows else 0
    if width < 2:
        raise LogError("expected at least two columns: time (s) and pressure", path)
    t_col, p_col, time_scale = _columns(header, width)
    warnings: list[str] = []
    times: list[float] = []
    values: list[float] = []
    bad = 0
    for row in rows:
        try:
            times.append(float(row[t_col]) * time_scale)
            values.append(float(row[p_col]))
        except (ValueError, IndexError):
            bad += 1
            if len(times) > len(values):
                times.pop()
    if bad:
        warnings.append(f"{bad} unreadable rows skipped in {path.name}")
    if not values:
        raise LogError("no rows of numbers in the pressure CSV", path)
    t_s = np.asarray(times, dtype=np.float64)
    p, converted = _in_pa(np.asarray(values, dtype=np.float64), path)
    if converted:
        warnings.append(converted)
    order = np.argsort(t_s, kind="stable")
    stamp_ns = np.round(t_s[order] * 1e9).astype(np.int64)
    return PressureSeries(stamp_ns=stamp_ns, pressure_pa=p[order], frame_id=path.stem), warnings


def _columns(header: list[str] | None, width: int) -> tuple[int, int, float]:
    """The time and pressure columns and the factor from the time column's unit to seconds."""
    t_col, p_col = 0, width - 1
    time_scale = 1.0
    if header is not None:
        named_p = [i for i, h in enumerate(header) if "pres" in h or h in ("p", "p_pa", "p_hpa")]
        if named_p:
            p_col = named_p[0]
        named_t = [i for i, h in enumerate(header) if h in ("t", "time", "stamp", "t_s", "time_s", "stamp_ns")]
        if named_t:
            t_col = named_t[0]
        if header[t_col].endswith("_ns"):
            time_scale = 1e-9
    return t_col, p_col, time_scale


def _in_pa(p: F64, path: Path) -> tuple[F64, str]:
    """Pressures in Pa, the unit told by their median's magnitude, and a warning when converted
    ("" when not)."""
    median = float(np.median(p[np.isfinite(p)])) if np.any(np.isfinite(p)) else float("nan")
    for lo, hi, factor, unit in _UNIT_BY_MAGNITUDE:
        if lo <= median < hi:
            if unit == "Pa":
                return p * factor, ""
            return p * factor, f"pressure in {path.name} read as {unit} (median {median:g}), converted to Pa"
    raise LogError(f"pressure values around {median:g} are not Pa, hPa or kPa of indoor air", path)


def _read_getsensordata(path: Path, lines: list[str]) -> tuple[PressureSeries, list[str]]:
    """The Android 'GetSensorData' log (IPIN competitions): PRES;app time s;sensor time s;mbar;..."""
    times: list[float] = []
    values: list[float] = []
    for ln in lines:
        if not ln.startswith("PRES;"):
            continue
        fields = ln.split(";")
        try:
            times.append(float(fields[1]))
            values.append(float(fields[3]) * 100.0)
        except (ValueError, IndexError):
            continue
    if not values:
        raise LogError("no readable PRES lines in the GetSensorData log", path)
    t_s = np.asarray(times, dtype=np.float64)
    order = np.argsort(t_s, kind="stable")
    stamp_ns = np.round(t_s[order] * 1e9).astype(np.int64)
    pressure = np.asarray(values, dtype=np.float64)[order]
    return PressureSeries(stamp_ns, pressure, path.stem), [f"{path.name}: GetSensorData log, PRES lines in mbar"]


def segmentation_to_json(seg: FloorSegmentation) -> dict[str, Any]:
    """The floors.json dictionary (times in epoch seconds); x/y and connectors are left out."""
    return {
        "floors": [
            {
                "id": f.id,
                "elevation_m": round(f.elevation_m, 4),
                "pressure_pa": f.pressure_json(),
                "visits": [[s / 1e9, e / 1e9] for s, e in f.visits],
            }
            for f in seg.floors
        ],
        "transitions": [
            {
                "kind": t.kind.value,
                "from": t.from_floor,
                "to": t.to_floor,
                "t_start": t.start_ns / 1e9,
                "t_end": t.end_ns / 1e9,
                "height_change_m": round(t.height_change_m, 4),
            }
            for t in seg.transitions
        ],
    }


def write_floors_json(seg: FloorSegmentation, path: Path) -> None:
    """Write floors.json atomically (temp file in the same folder, then rename)."""
    text = json.dumps(segmentation_to_json(seg), indent=2) + "\n"
    try:
        write_text_atomic(path, text)
    except OSError as err:
        raise OutputError(f"cannot write floors.json ({err.strerror or err})", path) from err


def read_floors_json(path: Path) -> dict[str, Any]:
    """Load a floors.json / gt_floors.json, checking the keys every reader relies on."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as err:  # ValueError: JSONDecodeError and UnicodeDecodeError
        raise LogError(f"cannot read floors JSON ({err.__class__.__name__})", path) from err
    if not isinstance(data, dict) or not isinstance(data.get("floors"), list):
        raise LogError("expected an object with a 'floors' list", path)
    for floor in data["floors"]:
        if not {"id", "elevation_m"} <= set(floor):
            raise LogError("every floor needs 'id' and 'elevation_m'", path)
    data.setdefault("transitions", [])
    return data
