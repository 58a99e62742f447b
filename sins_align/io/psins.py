"""Reader for the PSINS "compact SIMU" text format, and the PSINS Euler-angle convention.

File format (PSINS ``imufile``; see ``sins_align/data/psins-lasergyro/README.md``)
---------------------------------------------------------------------------------
- Lines starting with ``%`` are comments; blank lines are ignored (anywhere in the file).
- Three header data lines, six numbers each:

  1. ``pitch0 roll0 yaw0`` (deg, PSINS convention, "maybe inaccurate"), ``VE0 VN0 VU0`` (m/s);
  2. ``lat0 lon0`` (deg), ``h0`` (m), ``t0`` (s), sampling interval (**ms**), ``g`` (m/s^2);
  3. gyro scale factors ``gf_x gf_y gf_z`` (arcsec/count), accelerometer scale factors
     ``af_x af_y af_z`` (ug*s/count, where 1 ug = 1e-6 * header g).

- Then one line per sample: ``gx gy gz ax ay az`` as counts of angle / velocity *increments*
  over the sample interval (PSINS writes integers; decimal counts are accepted).
  Sample ``k`` (1-based) is stamped ``t0 + k * ts``.

Axes: PSINS mounts the SIMU "X-Right, Y-Forward, Z-Up" (``body_axes = 'RFU'``); the navigation
frame is ENU. The rates and forces returned here stay in the file's own body axes.

PSINS Euler convention (``a2mat`` / ``m2att``)
---------------------------------------------
``att = [pitch, roll, yaw]`` with ``C_b^n = Rz(yaw) @ Rx(pitch) @ Ry(roll)``, n = ENU.
Yaw is the azimuth of the body *Y* (forward) axis, **counter-clockwise** from North
(true heading of the forward axis = ``-yaw``). This is not REP-103 (``Rz Ry Rx``, yaw of the
body x axis from East); convert through the DCM.
"""
from __future__ import annotations

import lzma
import os
from dataclasses import dataclass

import numpy as np

ARCSEC = np.pi / 180.0 / 3600.0   # arcsec -> rad

_HEADER_NAMES = (
    "attitude/velocity line [pitch0 roll0 yaw0 (deg), VE0 VN0 VU0 (m/s)]",
    "position/timing line [lat0 lon0 (deg), h0 (m), t0 (s), ts (ms), g (m/s^2)]",
    "scale-factor line [gf_x gf_y gf_z (arcsec), af_x af_y af_z (ug*s)]",
)


@dataclass
class PsinsLog:
    """A PSINS compact-SIMU log converted to SI rates.

    Attributes
    ----------
    t : ndarray (N,), s — sample stamps ``t0 + k * ts``, k = 1..N (end of each interval).
    gyro : ndarray (N, 3), rad/s — mean angular rate over each interval (increment / ts),
        in the file's body axes.
    accel : ndarray (N, 3), m/s^2 — mean specific force (velocity increment / ts), same axes.
    ts : float, s — sampling interval (the header gives it in ms).
    lat_rad, lon_rad : float, rad — header position.
    height_m : float, m — header height.
    g_header : float, m/s^2 — header g, the unit behind the accelerometer's ug.
    att0_deg : ndarray (3,), deg — header [pitch, roll, yaw], PSINS convention
        (``psins_att_to_dcm``). PSINS flags it "maybe inaccurate": typically only a coarse yaw.
    vel0 : ndarray (3,), m/s — header [VE, VN, VU].
    gyro_scale_arcsec : ndarray (3,), arcsec/count.
    accel_scale_ugs : ndarray (3,), ug*s/count.
    t0 : float, s — header start time.
    body_axes : str — body axes of ``gyro``/``accel``: 'RFU' = X-Right, Y-Forward, Z-Up.
    """

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    ts: float
    lat_rad: float
    lon_rad: float
    height_m: float
    g_header: float
    att0_deg: np.ndarray
    vel0: np.ndarray
    gyro_scale_arcsec: np.ndarray
    accel_scale_ugs: np.ndarray
    t0: float = 0.0
    body_axes: str = "RFU"

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.t.shape[0])

    @property
    def duration(self) -> float:
        """Covered time span ``N * ts``, s."""
        return self.n * self.ts


#: first bytes of every xz file (the .xz container's magic number)
XZ_MAGIC = b"\xfd7zXZ\x00"


def read_text(path: str | os.PathLike) -> str:
    """The text of a log file, decompressed when it is an xz file (told by its first bytes,
    not its name). UTF-8; undecodable bytes become U+FFFD (the parsers report the line).

    Raises
    ------
    OSError — the file cannot be read. ValueError — it starts like an xz file but does
    not decompress (truncated, corrupted).
    """
    name = os.fspath(path)
    try:
        with open_text(name) as fh:
            return fh.read()
    except (lzma.LZMAError, EOFError) as e:
        raise ValueError(f"{name}: not a readable xz file ({e})") from None


def open_text(path: str | os.PathLike, encoding: str = "utf-8"):
    """A text log opened for reading, through xz when its first bytes are the xz magic
    number (not told by its name); undecodable bytes become U+FFFD. Reading a truncated or
    corrupted xz file raises ``lzma.LZMAError`` or ``EOFError``."""
    with open(path, "rb") as fh:
        xz = fh.read(len(XZ_MAGIC)) == XZ_MAGIC
    opener = lzma.open if xz else open
    return opener(path, "rt", encoding=encoding, errors="replace")


def _is_skipped(parts: list[str]) -> bool:
    return not parts or parts[0].startswith("%")


def _parse_header_line(name: str, lineno: int, line: str, which: int) -> np.ndarray:
    parts = line.split()
    if len(parts) != 6:
        raise ValueError(f"{name}:{lineno}: header {_HEADER_NAMES[which]} must have 6 fields, "
                         f"got {len(parts)}: {line.strip()!r}")
    try:
        vals = np.array([float(p) for p in parts])
    except ValueError:
        raise ValueError(f"{name}:{lineno}: header {_HEADER_NAMES[which]} is not numeric: "
                         f"{line.strip()!r}") from None
    if not np.all(np.isfinite(vals)):
        raise ValueError(f"{name}:{lineno}: header {_HEADER_NAMES[which]} has non-finite "
                         f"values: {line.strip()!r}")
    return vals


def read_psins(path: str | os.PathLike, max_samples: int | None = None) -> PsinsLog:
    """Read a PSINS compact-SIMU text log.

    Parameters
    ----------
    path : str or PathLike — the ``.imu`` text file, or that file compressed with xz
        (``.imu.xz``, e.g. :data:`sins_align.data.LASERGYRO`), read the same way.
    max_samples : int, optional — read at most this many data lines (must be >= 1).

    Returns
    -------
    PsinsLog — rates (rad/s) and specific forces (m/s^2) in the file's body axes.

    Raises
    ------
    ValueError
        An xz file that does not decompress, or a malformed file, with the file name and 1-based
        line number: missing or wrong header lines (each must have 6 finite numbers; ts, g and the
        scale factors must be positive, |lat| <= 90 deg), a data line without exactly 6 fields, a
        non-numeric or non-finite value, or no data line at all.
    """
    name = os.fspath(path)
    if max_samples is not None and (int(max_samples) != max_samples or max_samples < 1):
        raise ValueError(f"max_samples must be a positive integer, got {max_samples!r}")
    lines = read_text(name).splitlines()

    # --- the three header data lines -------------------------------------------------------
    header: list[np.ndarray] = []
    i = 0
    while i < len(lines) and len(header) < 3:
        if not _is_skipped(lines[i].split()):
            header.append(_parse_header_line(name, i + 1, lines[i], len(header)))
        i += 1
    if len(header) < 3:
        raise ValueError(f"{name}:{len(lines)}: end of file after {len(header)} of 3 header "
                         f"data lines (expected {_HEADER_NAMES[len(header)]})")
    header_end = i  # lines[header_end:] is the data part (0-based)
    h1, h2, h3 = header
    lat_deg, lon_deg, height, t0, ts_ms, g = h2
    if ts_ms <= 0.0:
        raise ValueError(f"{name}: header sampling interval must be > 0 ms, got {ts_ms}")
    if g <= 0.0:
        raise ValueError(f"{name}: header g must be > 0, got {g}")
    if abs(lat_deg) > 90.0:
        raise ValueError(f"{name}: header latitude {lat_deg} deg is outside [-90, 90]")
    if np.any(h3 <= 0.0):
        raise ValueError(f"{name}: header scale factors must be > 0, got {h3.tolist()}")

    # --- data lines --------------------------------------------------------------------------
    tokens: list[str] = []
    linenos: list[int] = []
    limit = max_samples if max_samples is not None else -1
    for j in range(header_end, len(lines)):
        parts = lines[j].split()
        if _is_skipped(parts):
            continue
        if len(parts) != 6:
            raise ValueError(f"{name}:{j + 1}: data line must have 6 fields "
                             f"(gx gy gz ax ay az), got {len(parts)}: {lines[j].strip()!r}")
        tokens.extend(parts)
        linenos.append(j + 1)
        if len(linenos) == limit:
            break
    if not linenos:
        raise ValueError(f"{name}:{len(lines)}: no data lines after the header "
                         f"(header ends at line {header_end})")
    try:
        counts = np.array(tokens, dtype=float).reshape(-1, 6)
    except ValueError:
        for k, ln in enumerate(linenos):
            try:
                [float(x) for x in tokens[6 * k:6 * k + 6]]
            except ValueError:
                raise ValueError(f"{name}:{ln}: non-numeric value in data line: "
                                 f"{lines[ln - 1].strip()!r}") from None
        raise  # pragma: no cover - numpy rejected something Python's float accepts
    finite = np.isfinite(counts).all(axis=1)
    if not finite.all():
        ln = linenos[int(np.argmin(finite))]
        raise ValueError(f"{name}:{ln}: non-finite value in data line: "
                         f"{lines[ln - 1].strip()!r}")

    ts = ts_ms * 1e-3
    gyro = counts[:, :3] * (h3[:3] * ARCSEC / ts)
    accel = counts[:, 3:] * (h3[3:] * 1e-6 * g / ts)
    t = t0 + ts * np.arange(1, counts.shape[0] + 1)
    return PsinsLog(t=t, gyro=gyro, accel=accel, ts=float(ts),
                    lat_rad=float(np.deg2rad(lat_deg)), lon_rad=float(np.deg2rad(lon_deg)),
                    height_m=float(height), g_header=float(g),
                    att0_deg=h1[:3].copy(), vel0=h1[3:].copy(),
                    gyro_scale_arcsec=h3[:3].copy(), accel_scale_ugs=h3[3:].copy(),
                    t0=float(t0), body_axes="RFU")


def psins_att_to_dcm(att_rad: np.ndarray) -> np.ndarray:
    """PSINS ``a2mat``: C_b^n (n = ENU) from ``[pitch, roll, yaw]``, rad.

    ``C = Rz(yaw) @ Rx(pitch) @ Ry(roll)``; yaw is counter-clockwise from North (of the body
    Y axis). Accepts shape (..., 3), returns (..., 3, 3).
    """
    a = np.asarray(att_rad, dtype=float)
    si, sj, sk = np.sin(a[..., 0]), np.sin(a[..., 1]), np.sin(a[..., 2])
    ci, cj, ck = np.cos(a[..., 0]), np.cos(a[..., 1]), np.cos(a[..., 2])
    C = np.empty(a.shape[:-1] + (3, 3))
    C[..., 0, 0] = cj * ck - si * sj * sk
    C[..., 0, 1] = -ci * sk
    C[..., 0, 2] = sj * ck + si * cj * sk
    C[..., 1, 0] = cj * sk + si * sj * ck
    C[..., 1, 1] = ci * ck
    C[..., 1, 2] = sj * sk - si * cj * ck
    C[..., 2, 0] = -ci * sj
    C[..., 2, 1] = si
    C[..., 2, 2] = ci * cj
    return C


def dcm_to_psins_att(C: np.ndarray) -> np.ndarray:
    """PSINS ``m2att``: ``[pitch, roll, yaw]``, rad, from C_b^n (n = ENU).

    pitch = asin(C32) in [-pi/2, pi/2] (computed as atan2), roll = atan2(-C31, C33), yaw =
    atan2(-C12, C22).
    At gimbal lock (cos(pitch) < 1e-9) roll is set to 0 and yaw = atan2(C21, C11), so
    ``psins_att_to_dcm(dcm_to_psins_att(C))`` still equals C. (PSINS switches branches already
    at |C32| > 0.999999, i.e. 0.08 deg from +-90 deg, which loses up to ~1e-3 rad there; the
    regular branch is exact much closer to the lock, so it is kept until cos(pitch) < 1e-9.)
    Accepts shape (..., 3, 3), returns (..., 3).
    """
    C = np.asarray(C, dtype=float)
    cp = np.hypot(C[..., 2, 0], C[..., 2, 2])
    lock = cp < 1e-9
    # atan2 form of asin(C32): same value for a rotation matrix, accurate near +-90 deg
    pitch = np.arctan2(C[..., 2, 1], cp)
    roll = np.where(lock, 0.0, np.arctan2(-C[..., 2, 0], C[..., 2, 2]))
    yaw = np.where(lock, np.arctan2(C[..., 1, 0], C[..., 0, 0]),
                   np.arctan2(-C[..., 0, 1], C[..., 1, 1]))
    return np.stack([pitch, roll, yaw], axis=-1)
