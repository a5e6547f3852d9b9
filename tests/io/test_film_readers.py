"""Readers of the side-scan (XTF), multibeam (R2Sonic in XTF) and single-beam (Imagenex 852)
recordings: the real files in ``../shared/data/real`` (skipped when absent), cut and corrupted
copies of them in ``tmp_path``, and foreign content.
"""

from __future__ import annotations

import dataclasses
import struct
from pathlib import Path

import numpy as np
import pytest

from sonarsim.image.films import Envelope, PingGeometry, Soundings, Waterfall
from sonarsim.io import readers
from sonarsim.io.readers import RecordingError

try:
    import pyxtf  # noqa: F401

    HAVE_PYXTF = True
except ImportError:
    HAVE_PYXTF = False
needs_pyxtf = pytest.mark.skipif(not HAVE_PYXTF, reason="pyxtf (the xtf extra) is not installed")

def open_recording_any(path):
    return readers.open_recording(path, film="any")


REAL = Path(__file__).resolve().parents[3] / "shared" / "data" / "real"
SIDESCAN = REAL / "sidescan" / "iver2_seascan_pings_0-179.xtf"
MULTIBEAM = REAL / "multibeam" / "r2sonic2026_pings_0-459.xtf"
SINGLEBEAM = REAL / "singlebeam" / "imagenex852_2016-11-18.852"
needs_data = pytest.mark.skipif(not REAL.is_dir(), reason="../shared/data/real is absent")

FILES = {"xtf": SIDESCAN, "r2sonic": MULTIBEAM, "imagenex852": SINGLEBEAM}


def need(fmt: str) -> None:
    """Skip a test of an XTF format when pyxtf is missing (the 852 reader needs nothing)."""
    if fmt != "imagenex852" and not HAVE_PYXTF:
        pytest.skip("pyxtf (the xtf extra) is not installed")


def packets(path: Path) -> list[tuple[int, int, int]]:
    """(type, offset, size) of every XTF packet, walked independently of the reader."""
    b = path.read_bytes()
    out, at = [], 1024
    while at < len(b):
        size = struct.unpack_from("<I", b, at + 10)[0]
        out.append((b[at + 2], at, size))
        at += size
    return out


# ------------------------------------------------------------------------------------------
# Recognition and registration
# ------------------------------------------------------------------------------------------


@needs_data
@pytest.mark.parametrize("fmt", sorted(FILES))
def test_formats_recognised_by_content_whatever_the_name(tmp_path, fmt):
    need(fmt)
    copy = tmp_path / "recording.bin"
    copy.write_bytes(FILES[fmt].read_bytes())
    assert readers.detect_format(copy) == fmt
    with open_recording_any(copy) as recording:
        assert type(recording) is readers.FORMATS[fmt]
        assert recording.film == readers.FILMS[fmt]
        assert fmt in repr(recording) or recording.units in repr(recording)


def test_json_starting_with_the_xtf_byte_is_not_xtf(tmp_path):
    p = tmp_path / "scene.json"
    p.write_text('{"sonar": {"preset": "aris1200"}}' + " " * 2000)
    with pytest.raises(RecordingError, match="not a recognised sonar recording"):
        readers.detect_format(p)


@pytest.mark.parametrize("content", [b"", b"\x00" * 5000, bytes(np.random.default_rng(0).integers(0, 256, 5000, np.uint8))])
def test_random_bytes_and_empty_file_refused(tmp_path, content):
    p = tmp_path / "x.xtf"
    p.write_bytes(content)
    with pytest.raises(RecordingError):
        open_recording_any(p)


def test_film_recordings_refuse_fan_pictures_by_name(tmp_path):
    if not REAL.is_dir():
        pytest.skip("../shared/data/real is absent")
    with open_recording_any(SINGLEBEAM) as recording:
        assert recording._repr_png_() is None
        with pytest.raises(RecordingError, match="envelope"):
            recording.plot()


# ------------------------------------------------------------------------------------------
# Side-scan
# ------------------------------------------------------------------------------------------


@needs_data
@needs_pyxtf
def test_sidescan_waterfall_and_geometry():
    w = readers.xtf.read_waterfall(SIDESCAN)
    assert isinstance(w, Waterfall)
    assert w.samples.shape == (180, 2, 1024) and w.samples.dtype == np.float32
    assert w.range_min_m == 0.0 and w.range_max_m == pytest.approx(29.9835, abs=1e-3)
    g = w.geometry
    # Ping 0 has no navigation: unknown, not zero; its time is there.
    for f in ("altitude_m", "depth_m", "pitch_deg", "roll_deg", "heading_deg", "latitude_deg", "speed_m_s"):
        assert np.isnan(getattr(g, f)[0]), f
        assert np.all(np.isfinite(getattr(g, f)[1:])), f
    assert np.all(np.isfinite(g.time_s)) and np.all(np.diff(g.time_s) > 0)
    assert g.time_s[-1] - g.time_s[0] == pytest.approx(22.05, abs=0.01)
    assert np.nanmin(g.depth_m) == pytest.approx(14.03, abs=0.01) and np.nanmax(g.depth_m) == pytest.approx(19.9, abs=0.01)
    assert np.nanmax(g.altitude_m) == pytest.approx(11.45, abs=0.01) and np.nanmin(g.altitude_m) == pytest.approx(6.21, abs=0.01)
    # SoundVelocity 750 is c/2: SlantRange = TimeDuration x 750.
    np.testing.assert_allclose(g.sound_speed_m_s, 1500.0)
    # Nose down while descending: ours > 0.
    assert 20.0 <= np.nanmin(g.pitch_deg) and np.nanmax(g.pitch_deg) <= 23.0
    # Speed in m/s from knots agrees with the distance between logged positions.
    ok = np.isfinite(g.x_m)
    dist = np.hypot(g.x_m[ok][-1] - g.x_m[ok][0], g.y_m[ok][-1] - g.y_m[ok][0])
    assert dist / (g.time_s[ok][-1] - g.time_s[ok][0]) == pytest.approx(np.nanmedian(g.speed_m_s), rel=0.1)
    # Depth + altitude: the floor is nearly flat.
    floor = g.depth_m + g.altitude_m
    assert 25.0 < np.nanmin(floor) and np.nanmax(floor) < 27.0


@needs_data
@needs_pyxtf
def test_sidescan_port_is_flipped_to_nadir_first():
    import pyxtf

    _, pk = pyxtf.xtf_read(str(SIDESCAN))
    w = readers.read(SIDESCAN, film="any", frame=5)
    np.testing.assert_array_equal(w.samples[0, 0], pk[0][5].data[0][::-1])
    np.testing.assert_array_equal(w.samples[0, 1], pk[0][5].data[1])
    # The saturated nadir is at sample 0 on both sides.
    assert np.all(w.samples[0, :, :5] == 32767)


@needs_data
@needs_pyxtf
def test_sidescan_first_bottom_return_lies_beyond_the_logged_altitude():
    """A threshold detector finds the first bottom return 1.3-1.9 m beyond the logged altitude
    (median about 1.6 m), not at it; h / cos(pitch) explains part of that (the fan is pitched)."""
    w = readers.xtf.read_waterfall(SIDESCAN, slice(1, None))
    first = first_return_m(w)
    d = first - w.geometry.altitude_m[:, None]
    assert 1.3 < np.median(d) < 1.9
    tilted = w.geometry.altitude_m / np.cos(np.radians(w.geometry.pitch_deg))
    assert 0.6 < np.median(first - tilted[:, None]) < 1.4


def first_return_m(w: Waterfall, factor: float = 4.0) -> np.ndarray:
    """Range of the first sample past the saturated nadir whose 5-sample mean exceeds ``factor``
    times the water column's median, ``(n_pings, 2)``."""
    s = w.samples.astype(np.float64)
    start = np.argmax(s[:, :, 5:] < 32767, axis=2) + 5 + 3
    k = np.arange(s.shape[2])
    after = k[None, None, :] >= start[..., None]
    cs = np.cumsum(np.where(after, s, 0.0), axis=2)
    mean5 = (cs[..., 4:] - np.concatenate([np.zeros(s.shape[:2] + (1,)), cs[..., :-5]], axis=2)) / 5.0
    column = np.where(after & (k < start[..., None] + 100), s, np.nan)
    base = np.nanmedian(column, axis=2)
    hit = (mean5 > factor * base[..., None]) & after[..., 4:] & after[..., :-4]
    return w.slant_range_m[np.argmax(hit, axis=2)]


# ------------------------------------------------------------------------------------------
# Multibeam
# ------------------------------------------------------------------------------------------


@needs_data
@needs_pyxtf
def test_multibeam_soundings_and_header():
    with open_recording_any(MULTIBEAM) as rec:
        s = rec.soundings()
        h = rec.header(0)
    assert isinstance(s, Soundings) and s.two_way_time_s.shape == (460, 256)
    assert h["ModelNumber"] == "2026" and h["Frequency"] == 400e3 and h["TxPulseWidth"] == pytest.approx(35e-6)
    assert np.all(np.isfinite(s.two_way_time_s))
    # Beam 0 port-most, angles > 0 to port, descending across the swath.
    assert np.all(np.diff(s.angle_deg, axis=1) < 0)
    assert 55 < s.angle_deg[0, 0] < 66 and -66 < s.angle_deg[0, -1] < -55
    g = s.geometry
    np.testing.assert_allclose(g.sound_speed_m_s, 1515.0, atol=0.5)
    for f in ("roll_deg", "pitch_deg", "heave_m", "heading_deg", "latitude_deg", "longitude_deg"):
        assert np.all(np.isfinite(getattr(g, f))), f
    assert np.all(np.abs(g.roll_deg) < 5.0)


def across_track_fits(s: Soundings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per ping, a line z = c0 + c1 y through the level soundings: (rms residual m, slope deg, depth m)."""
    p = s.level_points()
    y, z = p[..., 1], p[..., 2]
    ym, zm = y.mean(1, keepdims=True), z.mean(1, keepdims=True)
    c1 = ((y - ym) * (z - zm)).sum(1) / ((y - ym) ** 2).sum(1)
    c0 = zm[:, 0] - c1 * ym[:, 0]
    res = np.sqrt(np.mean((z - (c0[:, None] + c1[:, None] * y)) ** 2, axis=1))
    return res, np.degrees(np.arctan(c1)), -c0


def plane_rms(s: Soundings, window: int = 20) -> np.ndarray:
    """RMS residual of one plane through the soundings of each ``window`` consecutive pings (x along
    the track from the logged positions), metres."""
    p = s.level_points()
    g = s.geometry
    along = np.hypot(g.x_m - g.x_m[0], g.y_m - g.y_m[0])
    out = []
    for start in range(0, s.n_pings - window + 1, window):
        sel = slice(start, start + window)
        x = (along[sel, None] + p[sel, :, 0]).ravel()
        y, z = p[sel, :, 1].ravel(), p[sel, :, 2].ravel()
        a = np.c_[np.ones_like(x), y, x]
        c, *_ = np.linalg.lstsq(a, z, rcond=None)
        out.append(np.sqrt(np.mean((z - a @ c) ** 2)))
    return np.array(out)


def with_roll(s: Soundings, roll: np.ndarray) -> Soundings:
    d = s.geometry.as_dict()
    d["roll_deg"] = roll
    return dataclasses.replace(s, geometry=PingGeometry(**d))


@needs_data
@needs_pyxtf
def test_multibeam_roll_sign_one_plane_per_ping_and_per_stretch():
    """With each beam's angle corrected by the logged roll (REP-103), each ping's soundings lie on
    a line with a few cm residual, the line's across-track slope no longer follows the roll, and
    the soundings of 20 consecutive pings fit one plane within a few cm; the reversed roll sign
    makes the plane residual ten times worse."""
    s = readers.r2sonic.read_soundings(MULTIBEAM)
    res, slope, depth = across_track_fits(s)
    assert np.median(res) < 0.05 and res.max() < 0.08
    assert 10.0 < depth.min() and depth.max() < 11.0
    assert slope.std() < 0.3
    right = plane_rms(s)
    assert np.median(right) < 0.06 and right.max() < 0.09
    wrong = with_roll(s, -s.geometry.roll_deg)
    assert across_track_fits(wrong)[1].std() > 3.0
    assert np.median(plane_rms(wrong)) > 8 * np.median(right)
    # Uncorrected, the slope follows the roll one for one.
    raw = across_track_fits(with_roll(s, 0 * s.geometry.roll_deg))[1]
    assert np.corrcoef(raw, s.geometry.roll_deg)[0, 1] < -0.99


# ------------------------------------------------------------------------------------------
# Single-beam
# ------------------------------------------------------------------------------------------


@needs_data
def test_singlebeam_envelope_and_bottom():
    e = readers.imagenex.read_envelope(SINGLEBEAM)
    assert isinstance(e, Envelope) and e.samples.shape == (917, 500)
    assert (e.range_min_m, e.range_max_m) == (0.0, 10.0)
    found = np.isfinite(e.bottom_range_m)
    assert found.sum() == 452
    assert np.all((e.bottom_range_m[found] > 0.5) & (e.bottom_range_m[found] < 10.0))
    # The sounder's bottom is where the envelope peaks (profile range in cm).
    peak = e.range_m[np.argmax(e.samples[:, 10:], axis=1) + 10]
    assert np.median(np.abs(peak[found] - e.bottom_range_m[found])) <= 0.02
    g = e.geometry
    np.testing.assert_allclose(g.sound_speed_m_s, 1460.0)
    assert np.all(np.diff(g.time_s) > 0) and 900 < g.time_s[-1] - g.time_s[0] < 930
    assert np.all(np.isnan(g.roll_deg))


# ------------------------------------------------------------------------------------------
# Damaged files: the good pings before the damage, everywhere alike
# ------------------------------------------------------------------------------------------


def ping_offsets(fmt: str) -> list[int]:
    """Byte offset of every ping of the real file of ``fmt``."""
    if fmt == "imagenex852":
        return list(range(0, SINGLEBEAM.stat().st_size, 640))
    kind = 0 if fmt == "xtf" else 65
    return [at for t, at, _ in packets(FILES[fmt]) if t == kind]


def check_good(path: Path, n_good: int, damaged: bool) -> None:
    with open_recording_any(path) as rec:
        assert rec.n_frames == n_good
        assert (rec.damage is not None) == damaged
        rec.read(n_good - 1)
        if damaged:
            with pytest.raises(RecordingError, match=f"ping {n_good}"):
                rec.read(n_good)
            with pytest.raises(RecordingError, match="out of range"):
                rec.read(n_good + 1)
            with pytest.raises(RecordingError, match=f"ping {n_good}"):
                list(rec)
        else:
            assert len(list(rec)) == n_good
    assert readers.n_frames(path) == n_good


@needs_data
@pytest.mark.parametrize("fmt", sorted(FILES))
@pytest.mark.parametrize("where", ["inside the third ping", "just after the tenth", "two bytes into the last"])
def test_cut_files_keep_the_pings_before_the_cut(tmp_path, fmt, where):
    need(fmt)
    data = FILES[fmt].read_bytes()
    starts = ping_offsets(fmt)
    if where == "inside the third ping":
        cut, good = starts[2] + 200, 2
    elif where == "just after the tenth":
        cut, good = starts[10], 10
    else:
        cut, good = starts[-1] + 2, len(starts) - 1
    p = tmp_path / "cut"
    p.write_bytes(data[:cut])
    # Cut exactly at a ping boundary: a clean end for the 852 (whole records) and for XTF
    # unless what follows the last ping is cut (attitude packets come before pings here).
    damaged = not (where == "just after the tenth")
    check_good(p, good, damaged)


@needs_data
@pytest.mark.parametrize("fmt", sorted(FILES))
def test_corrupt_magic_of_one_ping_ends_the_good_pings(tmp_path, fmt):
    need(fmt)
    data = bytearray(FILES[fmt].read_bytes())
    at = ping_offsets(fmt)[7]
    data[at] ^= 0xFF  # the ping's first magic byte (0xFACE's low byte; '8' of '852')
    p = tmp_path / "corrupt"
    p.write_bytes(bytes(data))
    check_good(p, 7, True)
    with open_recording_any(p) as rec:
        assert "magic" in (rec.damage.field or "").lower() or "MagicNumber" in str(rec.damage)


@needs_data
@needs_pyxtf
def test_sidescan_huge_sample_count_refused_by_name(tmp_path):
    data = bytearray(SIDESCAN.read_bytes())
    at = ping_offsets("xtf")[3] + 256  # the first channel header of ping 3
    import pyxtf

    struct.pack_into("<I", data, at + pyxtf.XTFPingChanHeader.NumSamples.offset, 10**9)
    p = tmp_path / "huge.xtf"
    p.write_bytes(bytes(data))
    with open_recording_any(p) as rec:
        assert rec.n_frames == 3
        assert "NumSamples" in rec.damage.field and "1000000000" in rec.damage.detail


@needs_data
@needs_pyxtf
def test_multibeam_huge_point_count_refused_by_name(tmp_path):
    data = bytearray(MULTIBEAM.read_bytes())
    at = ping_offsets("r2sonic")[4]
    bth = data.find(b"BTH0", at)
    h0 = bth + 12
    struct.pack_into(">H", data, h0 + 4 + struct.calcsize(">12s12sIIIfffffffffHhfffffffIH"), 60000)
    p = tmp_path / "huge.xtf"
    p.write_bytes(bytes(data))
    with open_recording_any(p) as rec:
        assert rec.n_frames == 4
        assert rec.damage.field == "H0.Points"


@needs_data
def test_singlebeam_bad_bottom_and_sound_speed_refused(tmp_path):
    data = bytearray(SINGLEBEAM.read_bytes())
    data[5 * 640 + 108], data[5 * 640 + 109] = 0x00, 0x7F  # a bottom at 162 m in a 10 m window
    p = tmp_path / "bad.852"
    p.write_bytes(bytes(data))
    with open_recording_any(p) as rec:
        assert rec.n_frames == 5 and rec.damage.field == "profile range"


def test_missing_pyxtf_names_the_extra(tmp_path, monkeypatch):
    import builtins

    from sonarsim.errors import SonarsimError
    from sonarsim.io.readers import xtf

    real_import = builtins.__import__

    def no_pyxtf(name, *args, **kwargs):
        if name == "pyxtf":
            raise ImportError("No module named 'pyxtf'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_pyxtf)
    with pytest.raises(SonarsimError, match=r"xtf\]"):
        xtf._pyxtf()


@needs_data
@needs_pyxtf
def test_sidescan_positive_roll_brightens_starboard_near_nadir():
    """REP-103 roll > 0 lowers starboard: its beam looks closer to nadir, so just beyond nadir
    the starboard line is brighter than the port line as the roll grows (the sign check the
    side-scan data allow; the multibeam test is the firm one)."""
    w = readers.xtf.read_waterfall(SIDESCAN, slice(1, None))
    h = w.geometry.altitude_m[:, None]
    band = (w.slant_range_m >= h) & (w.slant_range_m < 1.1 * h)
    mean = (w.samples * band[:, None, :]).sum(2) / band.sum(1)[:, None]
    ratio = np.log(mean[:, 1] / mean[:, 0])
    assert np.corrcoef(ratio, w.geometry.roll_deg)[0, 1] > 0.4


@needs_data
@needs_pyxtf
def test_multibeam_corrupt_attitude_packet_between_pings(tmp_path):
    data = bytearray(MULTIBEAM.read_bytes())
    pk = packets(MULTIBEAM)
    pings = [i for i, (t, _, _) in enumerate(pk) if t == 65]
    between = next(i for i in range(pings[7] + 1, pings[8]) if pk[i][0] == 3)
    data[pk[between][1] + 1] ^= 0xFF
    p = tmp_path / "att.xtf"
    p.write_bytes(bytes(data))
    check_good(p, 8, True)
    with open_recording_any(p) as rec:
        assert f"packet {between}" in rec.damage.detail and rec.damage.field == "MagicNumber"
        s = rec.soundings()
        assert s.n_pings == 8 and np.all(np.isfinite(s.geometry.roll_deg))
        with pytest.raises(RecordingError, match="ping 8"):
            rec.soundings(slice(0, 20))


@needs_data
@needs_pyxtf
def test_readers_agree_with_the_module_functions():
    w = readers.xtf.read_waterfall(SIDESCAN, slice(10, 13))
    for i, k in enumerate(range(10, 13)):
        one = readers.read(SIDESCAN, film="any", frame=k)
        np.testing.assert_array_equal(one.samples[0], w.samples[i])
        assert one.geometry.time_s[0] == w.geometry.time_s[i]
    e = readers.imagenex.read_envelope(SINGLEBEAM, slice(3, 9, 2))
    np.testing.assert_array_equal(e.samples[1], readers.read(SINGLEBEAM, 5, film="envelope").samples[0])


@needs_data
@needs_pyxtf
def test_waterfall_beyond_the_memory_budget_is_refused_before_allocating(monkeypatch):
    monkeypatch.setenv("SONARSIM_MAX_MEMORY", "1M")
    with open_recording_any(SIDESCAN) as rec:
        rec.read(3)  # one ping fits
        with pytest.raises(RecordingError, match="NumSamples: a waterfall of 180 pings"):
            rec.waterfall()


def test_xtf_sample_formats():
    from sonarsim.io.readers.xtf import sample_dtype

    assert sample_dtype("f", 0, 2, 3) == "<u2" and sample_dtype("f", 0, 4, 5) == "<f4"
    assert sample_dtype("f", 0, 1, 0) == "<u1"
    with pytest.raises(RecordingError, match="SampleFormat 3 has 2-byte samples, but BytesPerSample is 4"):
        sample_dtype("f", 1, 4, 3)
    with pytest.raises(RecordingError, match="not supported"):
        sample_dtype("f", 1, 4, 1)  # IBM float


def test_xtf_sound_speed_rule():
    from sonarsim.io.readers.xtf import sound_speed

    assert sound_speed(750.0, 29.98, 0.03998) == 1500.0  # c/2, as in the test data
    assert sound_speed(1500.0, 29.98, 0.03998) == 1500.0  # c
    assert sound_speed(760.0, 10.0, 0.0) == 1520.0 and sound_speed(1490.0, 10.0, 0.0) == 1490.0


@needs_data
@pytest.mark.parametrize("fmt, cut, message", [
    ("xtf", 500, "truncated: it starts like an XTF file header .* ends at byte 500"),
    ("r2sonic", 1025, "truncated: it starts like an XTF file header"),
    ("imagenex852", 60, "truncated: it starts like an Imagenex 852 record"),
])
def test_files_cut_inside_their_first_header_are_named(tmp_path, fmt, cut, message):
    need(fmt)
    p = tmp_path / "cut"
    p.write_bytes(FILES[fmt].read_bytes()[:cut])
    with pytest.raises(RecordingError, match=message):
        open_recording_any(p)


@needs_data
@needs_pyxtf
def test_xtf_header_without_packet_magic(tmp_path):
    data = bytearray(SIDESCAN.read_bytes())
    data[1024] = 0
    p = tmp_path / "nomagic.xtf"
    p.write_bytes(bytes(data))
    with pytest.raises(RecordingError, match="byte 1024 holds 0xfa00, not the packet magic"):
        readers.detect_format(p)


@needs_data
@pytest.mark.parametrize("fmt, film", [("xtf", "waterfall"), ("r2sonic", "soundings"), ("imagenex852", "envelope")])
def test_programs_for_fls_frames_are_told_what_the_file_is(fmt, film):
    """open_recording's default (FLS frames: what sonarsim show, view and compare use) refuses
    the film formats by name and says how to read them."""
    need(fmt)
    with pytest.raises(RecordingError, match=f"this {fmt} recording holds {film} pings.*read it with"):
        readers.open_recording(FILES[fmt])
    with pytest.raises(RecordingError, match=film):
        readers.read(FILES[fmt], 0)
    with readers.open_recording(FILES[fmt], film=film) as rec:
        assert rec.film == film
    with pytest.raises(ValueError, match="film must be one of"):
        readers.open_recording(FILES[fmt], film="fan")


@needs_data
@pytest.mark.parametrize("fmt", sorted(FILES))
def test_corrupted_copies_give_recording_errors_only(tmp_path, fmt):
    """Random damage (bytes overwritten, cuts, words set to extremes) ends in good pings or a
    RecordingError, never another exception or a warning (seeded; fuzzed further with 1,500
    cases per format while writing the readers)."""
    need(fmt)
    import warnings

    data = FILES[fmt].read_bytes()
    rng = np.random.default_rng(7)
    read_all = {"xtf": "waterfall", "r2sonic": "soundings", "imagenex852": "envelope"}[fmt]
    p = tmp_path / "fuzz"
    for _ in range(40):
        b = bytearray(data)
        mode = rng.integers(3)
        if mode == 0:
            for _ in range(rng.integers(1, 6)):
                b[rng.integers(len(b))] = rng.integers(256)
        elif mode == 1:
            b = b[:rng.integers(len(b))]
        else:
            at = rng.integers(len(b) - 4)
            b[at:at + 4] = [b"\xff\xff\xff\xff", b"\x00\x00\x00\x00", b"\x7f\x7f\xff\xff", b"\x00\x00\xc0\x7f"][rng.integers(4)]
        p.write_bytes(bytes(b))
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            try:
                with open_recording_any(p) as rec:
                    if rec.format == fmt:
                        getattr(rec, read_all)()
                    for k in {0, rec.n_frames - 1, rec.n_frames} - {-1}:
                        try:
                            rec.read(k)
                        except RecordingError:
                            assert k == rec.n_frames
            except RecordingError:
                pass


def _h0_offset(field: str) -> int:
    """Byte offset of an H0 field from the section's start (after its name and size)."""
    import re

    from sonarsim.io.readers.r2sonic import _H0, _H0_FIELDS

    tokens = re.findall(r"\d*[a-zA-Z]", _H0.format[1:])  # one token per field
    return 4 + struct.calcsize(">" + "".join(tokens[:_H0_FIELDS.index(field)]))


def _xtf(struct_name: str, field: str) -> int:
    import pyxtf

    return getattr(getattr(pyxtf, struct_name), field).offset


@needs_data
@pytest.mark.parametrize("fmt, field, patch", [
    ("xtf", "NumChansToFollow", lambda b, at: struct.pack_into("<H", b, at + _xtf("XTFPingHeader", "NumChansToFollow"), 9)),
    ("xtf", "SlantRange", lambda b, at: struct.pack_into("<f", b, at + 256 + _xtf("XTFPingChanHeader", "SlantRange"), 1e6)),
    ("xtf", "SoundVelocity", lambda b, at: struct.pack_into("<f", b, at + _xtf("XTFPingHeader", "SoundVelocity"), 5.0)),
    ("r2sonic", "H0.SoundSpeed", lambda b, at: struct.pack_into(">f", b, b.find(b"BTH0", at) + 12 + _h0_offset("SoundSpeed"), 99.0)),
    ("r2sonic", "R0.ScalingFactor", lambda b, at: struct.pack_into(">f", b, b.find(b"R0", b.find(b"BTH0", at)) + 4, 3e38)),
    ("imagenex852", "range", lambda b, at: b.__setitem__(at + 107, 0)),
    ("imagenex852", "terminator", lambda b, at: b.__setitem__(at + 612, 0)),
    ("imagenex852", "data bytes", lambda b, at: b.__setitem__(at + 110, 0)),
    ("imagenex852", "date", lambda b, at: b.__setitem__(at + 11, ord("X"))),
])
def test_impossible_header_fields_end_the_good_pings_by_name(tmp_path, fmt, field, patch):
    need(fmt)
    data = bytearray(FILES[fmt].read_bytes())
    patch(data, ping_offsets(fmt)[6])
    p = tmp_path / "bad"
    p.write_bytes(bytes(data))
    with open_recording_any(p) as rec:
        assert rec.n_frames == 6
        assert field in rec.damage.field, rec.damage
        with pytest.raises(RecordingError, match="ping 6"):
            rec.read(6)
