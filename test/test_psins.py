"""Tests for the PSINS compact-SIMU reader, the PSINS Euler convention and coarse alignment.

The real log is the project's own copy, ``sins_align/data/psins-lasergyro/lasergyro.imu.xz``.
"""
import hashlib
import lzma

import numpy as np
import pytest

from sins_align.estimators.quasi_static.coarse import static_coarse_alignment
from sins_align.data import LASERGYRO as DATA
from sins_align.core.earth import OMEGA_IE, earth_rate_enu, gravity_enu
from sins_align.io.psins import (ARCSEC, dcm_to_psins_att, psins_att_to_dcm, read_psins)
from sins_align.core.rotation import attitude_error, heading_from_dcm, so3_exp

DEG = np.pi / 180.0
DPH = DEG / 3600.0

HEADER = """% PSINS-format SIMU log file.
% comment line

0.000000 0.000000 -90.600000 0.000000 0.000000 0.000000
34.24604800 108.90966400 380.000 0.00000000 10.00000000 9.780327
0.100000 0.100000 0.100000 125.000 125.000 125.000
"""


@pytest.fixture(scope="module")
def log():
    return read_psins(DATA)


@pytest.fixture(scope="module")
def calm(log):
    m = (log.t > 600.0) & (log.t <= 960.0)
    return log.gyro[m].mean(axis=0), log.accel[m].mean(axis=0)


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


# --------------------------------------------------------------------------- real file

def test_shipped_copy_is_the_original_file():
    """The xz copy decompresses to the original bytes named in its README (size and md5 of
    PSINS data/lasergyro.imu), and its LICENSE carries the BSD 2-clause copyright line."""
    raw = lzma.decompress(DATA.read_bytes())
    assert len(raw) == 2_665_416
    assert hashlib.md5(raw).hexdigest() == "62e1c12f345f9156146ac280ceaee280"
    folder = DATA.parent
    assert "62e1c12f345f9156146ac280ceaee280" in (folder / "README.md").read_text()
    lic = (folder / "LICENSE").read_text()
    assert "Copyright (c) 2009-2015, Gongmin Yan, All rights reserved." in lic
    assert "Redistribution and use in source and binary forms" in lic


def test_header_parsed_exactly(log):
    """Every header field of lasergyro.imu lands in the right attribute with the right unit."""
    assert log.lat_rad == np.deg2rad(34.246048)
    assert log.lon_rad == np.deg2rad(108.909664)
    assert log.height_m == 380.0
    assert log.t0 == 0.0
    assert log.ts == 0.01
    assert log.g_header == 9.780327
    np.testing.assert_array_equal(log.gyro_scale_arcsec, [0.1, 0.1, 0.1])
    np.testing.assert_array_equal(log.accel_scale_ugs, [125.0, 125.0, 125.0])
    np.testing.assert_array_equal(log.att0_deg, [0.0, 0.0, -90.6])
    np.testing.assert_array_equal(log.vel0, [0.0, 0.0, 0.0])
    assert log.body_axes == "RFU"


def test_length_and_time_stamps(log):
    """All 184,718 samples are read, stamped t0 + k*ts (k = 1..N), covering 1847.18 s."""
    assert log.n == 184718
    assert log.gyro.shape == (184718, 3) and log.accel.shape == (184718, 3)
    assert log.duration == pytest.approx(1847.18, abs=1e-9)
    assert log.t[0] == pytest.approx(0.01, abs=1e-12)
    assert log.t[-1] == pytest.approx(1847.18, abs=1e-9)
    np.testing.assert_allclose(np.diff(log.t), 0.01, atol=1e-9)


def test_first_and_last_samples_scaled_from_counts(log):
    """The first/last data lines ('0 0 2 0 0 80', '2 -4 7 0 2 80') become increment/ts in SI."""
    kg = 0.1 * ARCSEC / 0.01
    ka = 125e-6 * 9.780327 / 0.01
    np.testing.assert_allclose(log.gyro[0], np.array([0, 0, 2]) * kg, rtol=1e-14)
    np.testing.assert_allclose(log.accel[0], np.array([0, 0, 80]) * ka, rtol=1e-14)
    np.testing.assert_allclose(log.gyro[-1], np.array([2, -4, 7]) * kg, rtol=1e-14)
    np.testing.assert_allclose(log.accel[-1], np.array([0, 2, 80]) * ka, rtol=1e-14)


def test_mean_specific_force_magnitude(log):
    """|mean f| over the whole file is 9.7955 m/s^2 (README), i.e. the ug unit uses header g."""
    assert np.linalg.norm(log.accel.mean(axis=0)) == pytest.approx(9.7955, abs=1e-3)


def test_calm_window_resolves_earth_rate(log, calm):
    """In 600-960 s the mean gyro equals Earth rate: |w| = 15.04 deg/h, vertical = w_ie sin L.

    Proves the gyro unit (arcsec increments / ts) and that the z axis is Up, within 0.3 deg/h.
    """
    w, f = calm
    assert np.linalg.norm(w) / DPH == pytest.approx(OMEGA_IE / DPH, abs=0.3)
    up = f / np.linalg.norm(f)
    assert (w @ up) / DPH == pytest.approx(OMEGA_IE * np.sin(log.lat_rad) / DPH, abs=0.3)
    assert abs(OMEGA_IE / DPH - 15.04) < 0.01


def test_max_samples(log):
    """max_samples stops reading early and yields exactly the first rows of the full read."""
    part = read_psins(DATA, max_samples=1000)
    assert part.n == 1000
    np.testing.assert_array_equal(part.gyro, log.gyro[:1000])
    np.testing.assert_array_equal(part.accel, log.accel[:1000])
    np.testing.assert_array_equal(part.t, log.t[:1000])
    assert part.lat_rad == log.lat_rad
    with pytest.raises(ValueError):
        read_psins(DATA, max_samples=0)


def test_triad_reproduces_readme_row(log, calm):
    """Double-vector alignment on the 600-960 s means gives README's (0.922, 0.362, -90.80) deg."""
    w, f = calm
    att = np.rad2deg(dcm_to_psins_att(static_coarse_alignment(w, f, log.lat_rad)))
    assert att[0] == pytest.approx(0.922, abs=0.05)
    assert att[1] == pytest.approx(0.362, abs=0.05)
    assert att[2] == pytest.approx(-90.80, abs=0.5)
    # and agrees with the header's coarse yaw of -90.6 deg to within a degree
    assert abs(att[2] - log.att0_deg[2]) < 1.0


# --------------------------------------------------------------------------- small files

def _write(tmp_path, text, name="x.imu"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_small_file_units_comments_blank_lines_crlf(tmp_path):
    """Comments/blank lines between data lines and CRLF endings are skipped; units are exact."""
    body = HEADER + "1 2 3 4 5 6\n\n% mid comment\n   % indented comment\n-1 0 0 0 0 -80\n"
    p = tmp_path / "crlf.imu"
    p.write_bytes(body.replace("\n", "\r\n").encode())
    lg = read_psins(p)
    assert lg.n == 2
    np.testing.assert_allclose(lg.gyro[0], np.array([1, 2, 3]) * 0.1 * ARCSEC / 0.01, rtol=1e-14)
    np.testing.assert_allclose(lg.accel[0], np.array([4, 5, 6]) * 125e-6 * 9.780327 / 0.01,
                               rtol=1e-14)
    np.testing.assert_allclose(lg.accel[1, 2], -80 * 125e-6 * 9.780327 / 0.01, rtol=1e-14)
    np.testing.assert_allclose(lg.t, [0.01, 0.02], atol=1e-15)


@pytest.mark.parametrize("text, line, what", [
    # header line 2 has 5 fields
    (HEADER.replace("380.000 0.00000000", "380.000"), 5, "6 fields"),
    # header line 3 non-numeric
    (HEADER.replace("125.000 125.000 125.000", "125.000 abc 125.000"), 6, "not numeric"),
    # only two header data lines
    ("% c\n0 0 0 0 0 0\n34 108 380 0 10 9.78\n", 3, "header"),
    # data line with 5 columns (line 8)
    (HEADER + "0 0 2 0 0 80\n0 0 2 0 80\n", 8, "6 fields"),
    # data line with 7 columns (trailing comment is not allowed)
    (HEADER + "0 0 2 0 0 80 % c\n", 7, "6 fields"),
    # non-numeric text in a data line (line 9)
    (HEADER + "0 0 2 0 0 80\n1 1 1 1 1 1\n0 0 x2 0 0 80\n", 9, "non-numeric"),
    # non-finite value
    (HEADER + "0 0 2 0 0 80\n0 nan 2 0 0 80\n", 8, "non-finite"),
    # header only, no data
    (HEADER + "\n% nothing\n", 8, "no data"),
])
def test_malformed_files_raise_with_line(tmp_path, text, line, what):
    """Each malformed file raises ValueError naming the file, the 1-based line, and the fault."""
    p = _write(tmp_path, text, "bad.imu")
    with pytest.raises(ValueError) as ei:
        read_psins(p)
    msg = str(ei.value)
    assert f"bad.imu:{line}:" in msg, msg
    assert what in msg, msg


def test_xz_file_reads_like_the_text_it_holds(tmp_path):
    """A log compressed with xz reads exactly as the plain file, whatever its name (the
    reader goes by the xz magic bytes); max_samples works on it too."""
    text = HEADER + "1 2 3 4 5 6\n% c\n-1 0 7 0 0 -80\n2 -4 7 0 2 80\n"
    plain = read_psins(_write(tmp_path, text, "plain.imu"))
    for name in ("packed.imu.xz", "packed.imu"):
        p = tmp_path / name
        p.write_bytes(lzma.compress(text.encode()))
        lg = read_psins(p)
        for field in ("t", "gyro", "accel", "att0_deg", "vel0"):
            np.testing.assert_array_equal(getattr(lg, field), getattr(plain, field))
        assert (lg.ts, lg.lat_rad, lg.g_header) == (plain.ts, plain.lat_rad, plain.g_header)
    assert read_psins(tmp_path / "packed.imu.xz", max_samples=2).n == 2


def test_broken_xz_file_raises_with_name(tmp_path):
    """A truncated xz file is a ValueError naming the file, not an LZMAError or EOFError;
    a malformed line inside an xz file is reported with its line number as usual."""
    packed = lzma.compress((HEADER + "0 0 2 0 0 80\n" * 2000).encode())
    p = tmp_path / "cut.imu.xz"
    p.write_bytes(packed[: len(packed) // 2])
    with pytest.raises(ValueError, match="cut.imu.xz: not a readable xz file"):
        read_psins(p)
    p = tmp_path / "bad.imu.xz"
    p.write_bytes(lzma.compress((HEADER + "0 0 2 0 0 80\n0 0 2 0 80\n").encode()))
    with pytest.raises(ValueError, match="bad.imu.xz:8: data line must have 6 fields"):
        read_psins(p)


def test_bad_header_values_rejected(tmp_path):
    """A zero sampling interval or a non-positive scale factor is rejected, not divided by."""
    p = _write(tmp_path, HEADER.replace("10.00000000", "0") + "0 0 0 0 0 80\n")
    with pytest.raises(ValueError, match="sampling interval"):
        read_psins(p)
    p = _write(tmp_path, HEADER.replace("125.000 125.000 125.000", "125 0 125") + "0 0 0 0 0 80\n")
    with pytest.raises(ValueError, match="scale factor"):
        read_psins(p)


# --------------------------------------------------------------------------- conventions

def test_a2mat_is_rz_rx_ry():
    """psins_att_to_dcm equals Rz(yaw) Rx(pitch) Ry(roll) built from elementary rotations."""
    rng = np.random.default_rng(1)
    for _ in range(20):
        p, r, y = rng.uniform(-np.pi, np.pi, 3)
        np.testing.assert_allclose(psins_att_to_dcm([p, r, y]), _rz(y) @ _rx(p) @ _ry(r),
                                   atol=1e-15)


def test_m2att_inverts_a2mat():
    """dcm_to_psins_att is the exact inverse of psins_att_to_dcm (angles and DCMs round-trip)."""
    rng = np.random.default_rng(2)
    n = 2000
    att = np.column_stack([rng.uniform(-np.pi / 2 + 1e-3, np.pi / 2 - 1e-3, n),
                           rng.uniform(-np.pi, np.pi, n), rng.uniform(-np.pi, np.pi, n)])
    back = dcm_to_psins_att(psins_att_to_dcm(att))
    np.testing.assert_allclose(back, att, atol=1e-12)
    # arbitrary DCMs, including gimbal lock (pitch = +-90 deg), round-trip through the angles
    C = so3_exp(rng.normal(size=(n, 3)) * 2.0)
    near = np.pi / 2 - np.array([0.0, 1e-12, 1e-8, 1e-5, 1e-3])
    special = np.concatenate([np.column_stack([near, np.full(5, 0.7), np.full(5, -2.0)]),
                              np.column_stack([-near, np.full(5, -1.1), np.full(5, 0.4)])])
    C = np.concatenate([C, psins_att_to_dcm(special)])
    np.testing.assert_allclose(psins_att_to_dcm(dcm_to_psins_att(C)), C, atol=1e-9)


def test_header_yaw_means_forward_points_east():
    """PSINS yaw -90.6 deg (CCW) puts body Y (forward) at true heading 90.6 deg, roughly East."""
    C = psins_att_to_dcm(np.deg2rad([0.0, 0.0, -90.6]))
    fwd = C[:, 1]  # body Y in ENU
    heading = np.rad2deg(np.arctan2(fwd[0], fwd[1])) % 360.0
    assert heading == pytest.approx(90.6, abs=1e-9)
    # body X (right) then points South-ish (180.6 deg), body Z stays up
    assert np.rad2deg(heading_from_dcm(C)) == pytest.approx(180.6, abs=1e-9)
    np.testing.assert_allclose(C[:, 2], [0, 0, 1], atol=1e-15)
    # positive pitch raises the nose (forward axis gets an Up component)
    assert psins_att_to_dcm(np.deg2rad([1.0, 0.0, -90.6]))[2, 1] > 0


# --------------------------------------------------------------------------- coarse alignment

def test_coarse_alignment_exact_on_analytic_vectors():
    """With f^b = -C^T g^n and w^b = C^T w_ie^n, double-vector alignment recovers C to 1e-9 rad."""
    rng = np.random.default_rng(3)
    for _ in range(200):
        C = so3_exp(rng.normal(size=3) * 2.0)
        lat = rng.uniform(-85.0, 85.0) * DEG
        f_b = -C.T @ gravity_enu(lat)
        w_b = C.T @ earth_rate_enu(lat)
        C_est = static_coarse_alignment(w_b, f_b, lat)
        np.testing.assert_allclose(C_est @ C_est.T, np.eye(3), atol=1e-12)
        assert np.linalg.norm(attitude_error(C, C_est)) < 1e-9


def test_coarse_alignment_degenerate_inputs():
    """At a pole, or with zero/non-finite vectors, heading is unobservable: ValueError."""
    with pytest.raises(ValueError, match="parallel"):
        static_coarse_alignment([0, 0, OMEGA_IE], [0, 0, 9.8], np.pi / 2)
    with pytest.raises(ValueError):
        static_coarse_alignment([0, 0, 0], [0, 0, 9.8], 0.5)
    with pytest.raises(ValueError):
        static_coarse_alignment([0, np.nan, 0], [0, 0, 9.8], 0.5)
