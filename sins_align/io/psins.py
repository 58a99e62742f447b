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

PSINS transfer-alignment ``.mat`` (:func:`read_psins_mat`)
----------------------------------------------------------
A MATLAB v5 file (``sins_align/data/psins-transfer-fog-mems/README.md``) with ``mimu``
(N x 7: dtheta xyz [rad], dv xyz [m/s], t [s] of a slave MEMS IMU), ``fogavp`` (M x 10: pitch,
roll, yaw [rad], vE vN vU [m/s], lat lon [rad], h [m], t [s] of a master FOG INS), and the
reference values ``eb0`` (gyro bias, rad/s), ``db0`` (accelerometer bias, m/s^2) and ``mu0``
(mounting misalignment of the slave relative to the master, rad). Both IMUs have RFU axes.
"""
from __future__ import annotations

import io
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


# ----------------------------------------------------------------------------- .mat
#: the variables a PSINS transfer-alignment .mat must hold, with their column counts
#: (None: a 3-vector)
MAT_VARIABLES = {"mimu": 7, "fogavp": 10, "eb0": None, "db0": None, "mu0": None}

#: largest relative deviation of one ``mimu`` interval from the mean interval
MAT_INTERVAL_TOLERANCE = 0.01


@dataclass
class PsinsMat:
    """A PSINS transfer-alignment ``.mat``: slave MEMS IMU, master INS records, references.

    Every attitude is of RFU body axes (X-Right, Y-Forward, Z-Up) in ENU; quaternions are
    ``[x, y, z, w]`` (ROS order, w >= 0) of the same rotation as the DCM ``C_b^n``.

    Attributes
    ----------
    t : ndarray (N,), s — the ``mimu`` time column (end of each increment's interval).
    gyro : ndarray (N, 3), rad/s — mean angular rate over each interval (dtheta / ts), RFU.
    accel : ndarray (N, 3), m/s^2 — mean specific force (dv / ts), RFU.
    ts : float, s — the sampling interval: the mean step of the time column (every step is
        within 1 % of it).
    master_t : ndarray (M,), s — times of the master records (same time base as ``t``).
    master_att : ndarray (M, 3), rad — the master's [pitch, roll, yaw] as in the file
        (PSINS convention, :func:`psins_att_to_dcm`).
    master_dcm : ndarray (M, 3, 3) — the master's C_b^n (its RFU body in ENU).
    master_quat : ndarray (M, 4) — the same as quaternions [x, y, z, w].
    master_vel : ndarray (M, 3), m/s — the master's velocity [vE, vN, vU].
    master_lat, master_lon : ndarray (M,), rad — geodetic latitude, longitude.
    master_height : ndarray (M,), m — height.
    eb0 : ndarray (3,), rad/s — reference gyro bias of the slave MEMS IMU (body axes).
    db0 : ndarray (3,), m/s^2 — reference accelerometer bias of the slave (body axes).
    mu0 : ndarray (3,), rad — mounting misalignment of the slave relative to the master
        (a rotation vector in the master's body axes, :func:`slave_attitude`).
    slave_dcm : ndarray (M, 3, 3) — the slave's true C_b^n at ``master_t``
        (:func:`slave_attitude` of ``master_dcm`` and ``mu0``).
    slave_quat : ndarray (M, 4) — the same as quaternions [x, y, z, w].
    body_axes : str — 'RFU' for both IMUs.
    """

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    ts: float
    master_t: np.ndarray
    master_att: np.ndarray
    master_dcm: np.ndarray
    master_quat: np.ndarray
    master_vel: np.ndarray
    master_lat: np.ndarray
    master_lon: np.ndarray
    master_height: np.ndarray
    eb0: np.ndarray
    db0: np.ndarray
    mu0: np.ndarray
    slave_dcm: np.ndarray
    slave_quat: np.ndarray
    body_axes: str = "RFU"

    @property
    def n(self) -> int:
        """Number of IMU samples."""
        return int(self.t.shape[0])

    @property
    def n_master(self) -> int:
        """Number of master records."""
        return int(self.master_t.shape[0])


def slave_attitude(master_dcm: np.ndarray, mu0: np.ndarray) -> np.ndarray:
    """The slave's C_b^n from the master's and the mounting misalignment ``mu0``.

    ``C_s^n = C_m^n @ exp((mu0 x))``: ``mu0`` is the small rotation from the master's body
    axes to the slave's, in the master's axes. Equivalently, PSINS's ``qmul(qnb_slave,
    rv2q(-mu0))`` is the master's attitude. The sign was checked on the shipped data (see
    ``sins_align/data/psins-transfer-fog-mems/README.md``): the yaw part of the mounting fitted
    to the MEMS gyro and accelerometer against the master agrees with ``+mu0``, not ``-mu0``.

    Parameters
    ----------
    master_dcm : ndarray (..., 3, 3) — C_m^n.
    mu0 : ndarray (3,), rad.

    Returns
    -------
    ndarray (..., 3, 3) — C_s^n.
    """
    from sins_align.core.rotation import so3_exp

    return np.asarray(master_dcm, dtype=float) @ so3_exp(np.asarray(mu0, dtype=float))


def _mat_array(name: str, mat: dict, key: str, columns: int | None) -> np.ndarray:
    """One variable of the .mat, checked: real, finite, of the expected shape."""
    if key not in mat:
        have = sorted(k for k in mat if not k.startswith("__"))
        raise ValueError(f"{name}: variable {key!r} missing (the file has: "
                         f"{', '.join(have) or 'no variables'})")
    a = mat[key]
    if not isinstance(a, np.ndarray) or a.dtype.kind not in "iuf":
        raise ValueError(f"{name}: variable {key!r} is not a real numeric array")
    a = a.astype(float)
    if columns is None:
        if a.size != 3:
            raise ValueError(f"{name}: variable {key!r} must have 3 elements, got shape "
                             f"{a.shape}")
        a = a.reshape(3)
    elif a.ndim != 2 or a.shape[1] != columns or a.shape[0] < 1:
        raise ValueError(f"{name}: variable {key!r} must be an (n, {columns}) array, got shape "
                         f"{a.shape}")
    if not np.isfinite(a).all():
        bad = np.argwhere(~np.isfinite(a))[0]
        where = f" (row {bad[0] + 1})" if a.ndim == 2 else ""
        raise ValueError(f"{name}: variable {key!r} has a non-finite value{where}")
    return a


def _increasing(name: str, key: str, t: np.ndarray):
    steps = np.diff(t)
    if steps.size and not (steps > 0.0).all():
        k = int(np.argmin(steps > 0.0))
        raise ValueError(f"{name}: {key} time does not increase at row {k + 2} "
                         f"({t[k]!r} s -> {t[k + 1]!r} s)")


def load_mat(path: str | os.PathLike) -> dict:
    """The variables of a MATLAB v5 ``.mat`` file (``scipy.io.loadmat``).

    Raises
    ------
    OSError — the file cannot be read. ValueError — with the file name, for anything that is
    not a readable v5/v6/v7 .mat (truncated, corrupted, not a .mat, or a v7.3 HDF5 file).
    """
    import scipy.io

    name = os.fspath(path)
    with open(name, "rb") as fh:
        data = fh.read()
    try:
        return scipy.io.loadmat(io.BytesIO(data))
    except NotImplementedError:
        raise ValueError(f"{name}: a MATLAB v7.3 (HDF5) file, which is not read here; save it "
                         f"with save(..., '-v7')") from None
    except Exception as e:   # noqa: BLE001 - scipy raises many kinds on corrupt input
        text = " ".join(str(e).split()) or type(e).__name__
        raise ValueError(f"{name}: not a readable MATLAB .mat file ({text})") from None


def read_psins_mat(path: str | os.PathLike) -> PsinsMat:
    """Read a PSINS transfer-alignment ``.mat`` (e.g. :data:`sins_align.data.TRANSFER_FOG_MEMS`).

    Increments become mean rates and specific forces (divided by the mean interval); the
    master's PSINS Euler angles become C_b^n and quaternions (:func:`psins_att_to_dcm`); the
    slave's true attitude at the master times is :func:`slave_attitude`.

    Raises
    ------
    OSError — the file cannot be read.
    ValueError — one line with the file name: not a readable .mat (truncated, corrupted), a
        variable missing or of the wrong shape or type, a non-finite value, a time column
        that does not increase, ``mimu`` intervals that differ from their mean by more
        than 1 %, fewer than 2 IMU samples, or a latitude beyond +-90 deg.
    """
    from sins_align.core.rotation import quat_from_dcm

    name = os.fspath(path)
    mat = load_mat(name)
    mimu, fog, eb0, db0, mu0 = (_mat_array(name, mat, key, cols)
                                for key, cols in MAT_VARIABLES.items())
    if mimu.shape[0] < 2:
        raise ValueError(f"{name}: mimu has {mimu.shape[0]} row; at least 2 are needed to "
                         f"know the sampling interval")
    t = mimu[:, 6].copy()
    _increasing(name, "mimu", t)
    steps = np.diff(t)
    ts = float((t[-1] - t[0]) / (t.size - 1))
    dev = np.abs(steps - ts)
    if dev.max() > MAT_INTERVAL_TOLERANCE * ts:
        k = int(np.argmax(dev))
        raise ValueError(f"{name}: mimu is not uniformly sampled: step {steps[k]!r} s at row "
                         f"{k + 2}, mean {ts!r} s (increments need one interval)")
    master_t = fog[:, 9].copy()
    _increasing(name, "fogavp", master_t)
    lat = fog[:, 6]
    if np.abs(lat).max() > np.pi / 2:
        raise ValueError(f"{name}: fogavp latitude {np.rad2deg(np.abs(lat).max()):.3f} deg is "
                         f"beyond 90 deg (column 7 must be rad)")
    att = fog[:, 0:3].copy()
    dcm = psins_att_to_dcm(att)
    slave = slave_attitude(dcm, mu0)
    return PsinsMat(t=t, gyro=mimu[:, 0:3] / ts, accel=mimu[:, 3:6] / ts, ts=ts,
                    master_t=master_t, master_att=att, master_dcm=dcm,
                    master_quat=quat_from_dcm(dcm), master_vel=fog[:, 3:6].copy(),
                    master_lat=lat.copy(), master_lon=fog[:, 7].copy(),
                    master_height=fog[:, 8].copy(), eb0=eb0, db0=db0, mu0=mu0,
                    slave_dcm=slave, slave_quat=quat_from_dcm(slave), body_axes="RFU")
