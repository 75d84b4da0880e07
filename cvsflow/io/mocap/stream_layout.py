"""The layout of a pose-stream file: separator, header, which column holds what.

Used by the pose-stream formats (:mod:`cvsflow.io.mocap.asl`, ``tum``, ``eth``) to recognise a
file from its first lines and to find its columns (:mod:`cvsflow.io.mocap.streams` reads the
rows).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from cvsflow.io.mocap.markers import FileHead

#: Roles of a pose row, in the order of a positional row (t x y z qx qy qz qw).
ROLES = ("t", "x", "y", "z", "qx", "qy", "qz", "qw")
# Role -> pattern on the lower-cased, unit-stripped header name. EuRoC: p_RS_R_x, q_RS_w (the
# middle parts name frames); its velocity (v_*) and bias (b_w_*, b_a_*) columns match none.
_ROLE_PATTERNS = {
    "t": r"(timestamp|time|stamp|t)(_ns|_s|_us|_ms)?",
    "x": r"(x|tx|px|p_x|pos_x|position_x|x_m|p(_[a-z0-9]+)+_x)",
    "y": r"(y|ty|py|p_y|pos_y|position_y|y_m|p(_[a-z0-9]+)+_y)",
    "z": r"(z|tz|pz|p_z|pos_z|position_z|z_m|p(_[a-z0-9]+)+_z)",
    "qx": r"(qx|q_x|quat_x|rot_x|orientation_x|q(_[a-z0-9]+)+_x)",
    "qy": r"(qy|q_y|quat_y|rot_y|orientation_y|q(_[a-z0-9]+)+_y)",
    "qz": r"(qz|q_z|quat_z|rot_z|orientation_z|q(_[a-z0-9]+)+_z)",
    "qw": r"(qw|q_w|quat_w|rot_w|orientation_w|q(_[a-z0-9]+)+_w)",
}
_UNIT = re.compile(r"\[([^\]]*)\]")
_NS_INTEGER = re.compile(r"[+]?\d{16,}")  # 1e15 ns is 11.6 days: longer integers are ns since 1970


def looks_ns(time_text: str) -> bool:
    """Whether a time field is an integer of 16 or more digits: nanoseconds since 1970.

    Parameters
    ----------
    time_text : str
        The field as written.

    Returns
    -------
    bool
    """
    return bool(_NS_INTEGER.fullmatch(time_text.strip()))


def name_and_unit(raw: str) -> tuple[str, str | None]:
    """A header name without its unit, lower case, and the unit: ``'p_RS_R_x [m]'`` -> ``('p_rs_r_x', 'm')``.

    Parameters
    ----------
    raw : str
        The header cell as written (a leading ``#`` allowed).

    Returns
    -------
    name : str
    unit : str or None
    """
    unit = _UNIT.search(raw)
    name = _UNIT.sub("", raw).strip().lstrip("#").strip().lower().replace(" ", "_")
    return name, (unit.group(1).strip().lower() if unit else None)


def header_roles(names) -> tuple[dict, list, dict, dict]:
    """Column of each role (t, x, y, z, qx, qy, qz, qw) found by name, and what is amiss.

    Parameters
    ----------
    names : sequence of str
        Header names as written (units in brackets allowed).

    Returns
    -------
    roles : dict
        role -> column index, for the roles exactly one column matches.
    missing : list of str
        Roles no column matches.
    ambiguous : dict
        role -> the names of the several columns that match it.
    units : dict
        role -> the unit in brackets, where given.
    """
    parsed = [name_and_unit(n) for n in names]
    roles, missing, ambiguous, units = {}, [], {}, {}
    for role, pattern in _ROLE_PATTERNS.items():
        hits = [i for i, (n, _) in enumerate(parsed) if re.fullmatch(pattern, n)]
        if len(hits) == 1:
            roles[role] = hits[0]
            if parsed[hits[0]][1]:
                units[role] = parsed[hits[0]][1]
        elif not hits:
            missing.append(role)
        else:
            ambiguous[role] = [names[i] for i in hits]
    return roles, missing, ambiguous, units


@dataclass
class StreamLayout:
    """What the start of a text file shows of a pose stream.

    Attributes
    ----------
    separator : {",", "whitespace"} or None
        Of the first data row (None: no data row).
    n_fields : int
        Fields of the first data row.
    first_data_line : int or None
        Its line number (1-based).
    first_time : str or None
        Its first field, as written.
    header : list of str or None
        The names on the line before it, when that line is text with as many fields.
    header_line : int or None
        That line's number.
    hashed : bool
        The header line starts with ``#`` (EuRoC's ``#timestamp``).
    roles, missing, ambiguous, units
        :func:`header_roles` of the header (empty without one).
    """

    separator: str | None = None
    n_fields: int = 0
    first_data_line: int | None = None
    first_time: str | None = None
    header: list | None = None
    header_line: int | None = None
    hashed: bool = False
    roles: dict = field(default_factory=dict)
    missing: list = field(default_factory=list)
    ambiguous: dict = field(default_factory=dict)
    units: dict = field(default_factory=dict)

    @property
    def names_all_roles(self) -> bool:
        """The header names each role exactly once."""
        return self.header is not None and not self.missing and not self.ambiguous

    @property
    def positional(self) -> bool:
        """The header's roles sit at positions 0..7 of an 8-field row."""
        order = [self.roles.get(r) for r in ROLES]
        return self.names_all_roles and self.n_fields == 8 and order == list(range(8))


def split_fields(line: str, separator: str | None) -> list[str]:
    """The fields of a line: comma separated (stripped) or whitespace separated.

    Parameters
    ----------
    line : str
    separator : {",", "whitespace"} or None
        None and ``"whitespace"`` split on runs of white space.

    Returns
    -------
    list of str
    """
    if separator == ",":
        return [f.strip() for f in line.split(",")]
    return line.split()


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return text.strip() != ""


def stream_layout(head: FileHead, max_lines: int = 200) -> StreamLayout:
    """The pose-stream layout of a file's first lines (computed once per head).

    Parameters
    ----------
    head : FileHead
        The file's start.
    max_lines : int
        Lines looked at.

    Returns
    -------
    StreamLayout
        Empty (``first_data_line`` None) when no line of numbers comes within ``max_lines``.
    """
    if "stream_layout" in head.memo:
        return head.memo["stream_layout"]
    lay = StreamLayout()
    prev = None  # (line number, text, hashed) of the last text line
    for lineno, raw in enumerate(head.lines[:max_lines], start=1):
        s = raw.strip()
        if not s:
            continue
        body = s.lstrip("#").strip()
        sep = "," if "," in body else "whitespace"
        fields = split_fields(body, sep)
        if s.startswith("#") or not all(_is_number(f) for f in fields):
            prev = (lineno, body, s.startswith("#"))
            continue
        lay = StreamLayout(sep, len(fields), lineno, fields[0])
        if prev is not None:
            names = split_fields(prev[1], "," if "," in prev[1] else "whitespace")
            if len(names) == len(fields) and not all(_is_number(n) for n in names):
                lay.header, lay.header_line, lay.hashed = names, prev[0], prev[2]
                lay.roles, lay.missing, lay.ambiguous, lay.units = header_roles(names)
        break
    head.memo["stream_layout"] = lay
    return lay


def describe_layout(lay: StreamLayout) -> str | None:
    """What a file's rows look like as a pose stream, for an error that no format matched.

    Parameters
    ----------
    lay : StreamLayout

    Returns
    -------
    str or None
        None when the file has no row of numbers that could be a pose.
    """
    if lay.first_data_line is None or (lay.n_fields < 7 and "t" not in lay.roles):
        return None  # no row that could be a pose
    sep = "comma" if lay.separator == "," else "whitespace"
    what = f"line {lay.first_data_line} holds {lay.n_fields} {sep}-separated numbers"
    if lay.header is not None and lay.missing:
        what += f"; its header names no column for {lay.missing}"
    elif lay.header is None and looks_ns(lay.first_time) and lay.separator == ",":
        what += (f", the time an integer of {len(lay.first_time.strip())} digits (ns), and no header "
                 "line names the columns (an ASL CSV needs one; ETH and TUM times are seconds)")
    elif lay.n_fields != 8 and lay.header is None:
        what += " (a TUM or ETH row has 8: t x y z qx qy qz qw)"
    return what
