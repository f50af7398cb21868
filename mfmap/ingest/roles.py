"""Topic roles: which topic of a log is read as its lidar, barometer, IMU, ... ."""

from __future__ import annotations

from pathlib import Path

from mfmap.errors import ConfigError, LogError
from mfmap.types import ROLE_BY_TYPE, Role

ROLE_TYPE: dict[Role, str] = {}
for _msgtype, _role in ROLE_BY_TYPE.items():
    ROLE_TYPE.setdefault(_role, _msgtype)  # the first (standard) type a role is named by


def assign_roles(
    topics: dict[str, tuple[str, int]], overrides: dict[str, str], path: Path
) -> tuple[dict[Role, str], list[str]]:
    """Pick one topic per role: config override, else the candidate with the most messages.

    `topics` maps name -> (msgtype, count). Returns the roles and notes for the user.
    """
    roles: dict[Role, str] = {}
    notes: list[str] = []
    for key, name in overrides.items():
        try:
            role = Role(key)
        except ValueError as err:
            valid = ", ".join(r.value for r in Role)
            raise ConfigError(f"ingest.topics: unknown role '{key}' (roles: {valid})") from err
        if name not in topics:
            known = ", ".join(sorted(topics)) or "none"
            raise LogError(f"topic '{name}' for role {role.value} is not in the log (topics: {known})", path)
        msgtype = topics[name][0]
        if ROLE_BY_TYPE.get(msgtype) != role:
            raise LogError(
                f"topic '{name}' has type {msgtype}; role {role.value} needs {ROLE_TYPE[role]}", path
            )
        roles[role] = name
    for role in Role:
        if role in roles:
            continue
        cands = [(n, c) for n, (t, c) in topics.items() if ROLE_BY_TYPE.get(t) == role and c > 0]
        if not cands:
            continue
        if role == Role.TF_STATIC:
            # /tf carries the same type with far more messages; the static tree is what we want.
            static = [nc for nc in cands if nc[0].rstrip("/").endswith("tf_static")]
            if not static:
                continue
            cands = static
        cands.sort(key=lambda nc: (-nc[1], nc[0]))
        roles[role] = cands[0][0]
        if len(cands) > 1:
            listed = ", ".join(f"{n} ({c} msgs)" for n, c in cands)
            notes.append(
                f"{role.value}: {len(cands)} candidate topics ({listed}); chose {cands[0][0]} "
                f"(most messages); override with --topic {role.value}=TOPIC"
            )
    return roles, notes
