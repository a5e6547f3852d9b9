"""Readers of real recordings (ARIS, Oculus) and the ``show`` command.

Most tests build files byte by byte from the documented layouts (aris-file-sdk
``FrameHeader.h``; Blueprint Subsea ``Oculus.h``) with known sample patterns, so they need no
data; the tests on the real recordings in ``../shared/data`` skip when it is absent.
"""

from __future__ import annotations

import argparse
import struct
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from sonarsim import SonarImage, SonarsimError
from sonarsim.io import readers
from sonarsim.config.presets import aris_beam_angles_deg, get_preset
from sonarsim.io.readers import RecordingError
from sonarsim.io.readers import aris as aris_module
from sonarsim.io.readers.oculus import elevation_fov_deg
from sonarsim.cli.show import add_show_parser, cmd_show

DATA = Path(__file__).resolve().parents[3] / "shared" / "data"
ARIS_SAMPLE = DATA / "real" / "aris" / "sample.aris"
OCULUS_ONE = DATA / "real" / "oculus" / "one_ping_8bit.raw"
OCULUS_THREE = DATA / "real" / "oculus" / "three_pings_8bit.raw"
needs_data = pytest.mark.skipif(not DATA.is_dir(), reason="../shared/data is absent")

ARIS_SIG = 0x05464444
PING_MODE_BEAMS = {1: 48, 3: 96, 6: 64, 9: 128}


# ------------------------------------------------------------------------------------------
# Builders
# ------------------------------------------------------------------------------------------


def aris_file_header(signature: int = ARIS_SIG, frame_count: int = 0) -> bytes:
    h = bytearray(1024)
    struct.pack_into("<II", h, 0, signature, frame_count)
    return bytes(h)


def aris_frame_header(
    *,
    index: int = 0,
    ping_mode: int = 1,
    samples_per_beam: int = 100,
    sample_period_us: int = 10,
    sound_speed: float = 1500.0,
    start_delay_us: int = 2000,
    large_lens: int = 0,
    system_type: int = 2,
    reordered: int = 1,
    high_frequency: int = 1,
    signature: int = ARIS_SIG,
) -> bytes:
    h = bytearray(1024)
    struct.pack_into("<I", h, 0, index)
    struct.pack_into("<I", h, 12, signature)
    struct.pack_into("<I", h, 436, ping_mode)
    struct.pack_into("<I", h, 440, high_frequency)
    struct.pack_into("<I", h, 452, sample_period_us)
    struct.pack_into("<f", h, 464, sound_speed)
    struct.pack_into("<I", h, 468, samples_per_beam)
    struct.pack_into("<I", h, 476, start_delay_us)
    struct.pack_into("<I", h, 480, large_lens)
    struct.pack_into("<I", h, 484, system_type)
    struct.pack_into("<I", h, 516, reordered)
    return bytes(h)


def aris_samples(n_samples: int, n_beams: int, bright: list[tuple[int, int]] = ()) -> bytes:
    """Samples in file order: data[sample, beam], beam 0 RIGHT-most; ``bright`` = (sample, beam)."""
    data = np.full((n_samples, n_beams), 10, dtype=np.uint8)
    for sample, beam in bright:
        data[sample, beam] = 250
    return data.tobytes()


def write_aris(path: Path, frames: list[tuple[dict, list[tuple[int, int]]]]) -> Path:
    """An ARIS file with one frame per (header keywords, bright (sample, file beam) list)."""
    out = bytearray(aris_file_header(frame_count=len(frames)))
    for k, (kw, bright) in enumerate(frames):
        kw = {"index": k, **kw}
        out += aris_frame_header(**kw)
        out += aris_samples(kw.get("samples_per_beam", 100), PING_MODE_BEAMS.get(kw.get("ping_mode", 1), 48), bright)
    path.write_bytes(bytes(out))
    return path


def oculus_message(
    image: np.ndarray,
    bearings_cdeg: np.ndarray,
    *,
    version: int = 1,
    data_size: int = 0,
    range_resolution: float = 0.01,
    frequency: float = 2.1e6,
    master_mode: int = 2,
    flags: int = 0x19,
    send_gain: bool = False,
    ping_id: int = 1,
    msg_id: int = 0x23,
    image_size: int | None = None,
    pad: int = 6,
) -> bytes:
    """A simple ping result message (v1 or v2) with ``image`` rows = ranges, columns = file beams."""
    n_ranges, n_beams = image.shape
    bpv = {0: 1, 1: 2, 2: 3, 3: 4}[data_size]
    if send_gain:
        flags |= 0x04
    if bpv == 3:
        v = image.astype("<u4")
        body = np.stack([(v >> s) & 0xFF for s in (0, 8, 16)], axis=-1).astype(np.uint8)
        rows = body.reshape(n_ranges, n_beams * 3)
    else:
        rows = image.astype(f"<u{bpv}").view(np.uint8).reshape(n_ranges, n_beams * bpv)
    if send_gain:
        gains = np.arange(1, n_ranges + 1, dtype="<u4").view(np.uint8).reshape(n_ranges, 4)
        rows = np.concatenate([gains, rows], axis=1)
    image_bytes = rows.tobytes()
    bearings = np.asarray(bearings_cdeg, dtype="<i2").tobytes()
    bearings_at = 122 if version in (0, 1) else 202
    image_offset = bearings_at + len(bearings) + pad
    total = image_offset + len(image_bytes)
    msg = bytearray(total)
    struct.pack_into("<HHHHHIH", msg, 0, 0x4F53, 7892, 0, msg_id, version, total - 16, 0)
    struct.pack_into("<BBBBBdddd", msg, 16, master_mode, 0, 0, 127, flags, 2.0, 50.0, 1500.0, 0.0)
    size = len(image_bytes) if image_size is None else image_size
    if version in (0, 1):
        struct.pack_into(
            "<IIddddIBdHHIII", msg, 53, ping_id, 0, frequency, 12.0, 1.0, 1490.0, 1234, data_size,
            range_resolution, n_ranges, n_beams, image_offset, size, total,
        )
    else:
        struct.pack_into("<I", msg, 53, 0x200)  # extFlags
        struct.pack_into(
            "<IIddddddddBdHHIIIIIII", msg, 89, ping_id, 0, frequency, 12.0, 1.0, 10.0, 1.0, 2.0,
            1490.0, 3.5, data_size, range_resolution, n_ranges, n_beams, 0, 0, 0, 0,
            image_offset, size, total,
        )
    msg[bearings_at:bearings_at + len(bearings)] = bearings
    msg[image_offset:] = image_bytes
    return bytes(msg)


def ascending_bearings(n_beams: int, half_deg: float = 30.0) -> np.ndarray:
    """Bearings in 0.01 deg as an Oculus sends them: most negative (port) first."""
    return np.round(np.linspace(-half_deg, half_deg, n_beams) * 100).astype(np.int16)


def bright_image(n_ranges: int, n_beams: int, spots: list[tuple[int, int, int]]) -> np.ndarray:
    img = np.full((n_ranges, n_beams), 5, dtype=np.uint32)
    for r, b, v in spots:
        img[r, b] = v
    return img


# ------------------------------------------------------------------------------------------
# ARIS, synthetic
# ------------------------------------------------------------------------------------------


def test_aris_bright_sample_lands_in_left_most_first_column(tmp_path):
    # File beam 5 of 48 (counted from the right) at sample 40 -> column 48 - 1 - 5 = 42.
    path = write_aris(tmp_path / "one.aris", [({}, [(40, 5)])])
    image = readers.read(path)
    assert isinstance(image, SonarImage)
    assert image.polar.dtype == np.float32 and image.polar.shape == (100, 48)
    assert image.polar.flags.c_contiguous
    rows, cols = np.nonzero(image.polar == 250)
    assert rows.tolist() == [40] and cols.tolist() == [42]
    assert image.components["total"] is image.polar
    assert image.rays is None
    assert image.config["format"] == "aris" and image.config["frame"] == 0
    assert image.config["source"] == str(path)
    assert image.config["header"]["PingMode"] == 1


def test_a_recording_has_intrinsics_but_no_pose(tmp_path):
    # Neither format records where the sonar was: the image says so rather than inventing one.
    aris = readers.read(write_aris(tmp_path / "one.aris", [({}, [(40, 5)])]))
    path = tmp_path / "one.raw"
    path.write_bytes(oculus_message(bright_image(50, 16, [(30, 3, 200)]), ascending_bearings(16)))
    oculus = readers.read(path)
    for image in (aris, oculus):
        assert image.pose is None
        assert image.sonar.n_beams == image.polar.shape[1]


def test_aris_range_axis_from_header_fields(tmp_path):
    # start = 2000 us * 1500 / 2 = 1.5 m; sample = 10 us * 1500 / 2 = 7.5 mm; 100 samples.
    path = write_aris(tmp_path / "r.aris", [({}, [])])
    image = readers.read(path)
    s = image.sonar
    assert s.range_min_m == pytest.approx(1.5)
    assert s.range_max_m == pytest.approx(1.5 + 100 * 0.0075)
    assert s.n_range_bins == 100
    assert image.range_m[0] == pytest.approx(1.5 + 0.5 * 0.0075)
    assert np.allclose(np.diff(image.range_m), 0.0075)
    assert s.elevation_fov_deg == 14.0
    assert s.frequency_khz == 1200.0  # ARIS 1200, high frequency
    h = image.config["header"]
    assert h["window_start_m"] == pytest.approx(1.5) and h["sample_length_m"] == pytest.approx(0.0075)


@pytest.mark.parametrize(
    "system_type, large_lens, ping_mode, model_key, n_beams",
    [
        (2, 0, 1, "ARIS1200", 48),
        (2, 1, 1, "ARIS-telephoto", 48),
        (0, 0, 1, "ARIS1800", 48),
        (0, 0, 3, "ARIS1800", 96),
        (0, 1, 3, "ARIS-telephoto", 96),
        (1, 0, 6, "ARIS3000", 64),
        (1, 0, 9, "ARIS3000", 128),
    ],
)
def test_aris_beam_angles_from_system_type_and_lens(tmp_path, system_type, large_lens, ping_mode, model_key, n_beams):
    kw = {"system_type": system_type, "large_lens": large_lens, "ping_mode": ping_mode, "samples_per_beam": 20}
    path = write_aris(tmp_path / "b.aris", [(kw, [])])
    image = readers.read(path)
    expected = aris_beam_angles_deg(model_key, n_beams)
    assert image.polar.shape == (20, n_beams)
    np.testing.assert_allclose(image.azimuth_deg, expected)
    np.testing.assert_allclose(image.sonar.beam_angles_deg, expected)
    assert image.azimuth_deg[0] > 0 > image.azimuth_deg[-1]  # left-most (positive) first
    assert np.all(np.diff(image.azimuth_deg) < 0)


@pytest.mark.parametrize(
    "system_type, large_lens, ping_mode, preset, elevation",
    [
        (2, 0, 1, "aris1200-48", 14.0),
        (2, 1, 1, "aris1200-48-telephoto", 3.0),
        (0, 0, 1, "aris1800-48", 14.0),
        (0, 1, 1, "aris1800-48-telephoto", 3.0),
        (0, 0, 3, "aris1800-96", 14.0),
        (0, 1, 3, "aris1800-96-telephoto", 3.0),
        (1, 0, 6, "aris3000-64", 14.0),
        (1, 0, 9, "aris3000-128", 14.0),
    ],
)
def test_aris_lens_gives_the_elevation_aperture_and_the_preset(tmp_path, system_type, large_lens, ping_mode,
                                                               preset, elevation):
    # The lens is LargeLens in the frame header; 14 deg for every lens was the old assumption.
    kw = {"system_type": system_type, "large_lens": large_lens, "ping_mode": ping_mode, "samples_per_beam": 20}
    image = readers.read(write_aris(tmp_path / "lens.aris", [(kw, [])]))
    assert image.sonar.elevation_fov_deg == elevation
    assert image.sonar.preset == preset
    assert image.config["header"]["elevation_fov_deg_assumed"] == elevation
    assert image.config["header"]["lens"] == ("telephoto" if large_lens else "standard")
    # The preset it names has the same beams and aperture (the window is the recording's).
    named = get_preset(preset).sonar
    assert named["n_beams"] == image.sonar.n_beams and named["elevation_fov_deg"] == elevation
    np.testing.assert_allclose(named["beam_angles_deg"], image.sonar.beam_angles_deg, atol=1e-6)


def test_aris_lens_changes_only_the_aperture_within_one_file_header(tmp_path):
    # Two frames, standard then telephoto lens (a lens swap between recordings written to one file).
    path = write_aris(tmp_path / "two.aris", [({"large_lens": 0}, []), ({"large_lens": 1}, [])])
    first, second = readers.read(path, 0), readers.read(path, 1)
    assert (first.sonar.elevation_fov_deg, second.sonar.elevation_fov_deg) == (14.0, 3.0)
    assert (first.sonar.preset, second.sonar.preset) == ("aris1200-48", "aris1200-48-telephoto")
    assert second.azimuth_deg[0] < first.azimuth_deg[0] / 1.5  # the telephoto fan is about half as wide


def test_aris_multiple_frames_and_frame_selection(tmp_path):
    frames = [({}, [(10 + 20 * k, k)]) for k in range(3)]
    path = write_aris(tmp_path / "m.aris", frames)
    assert readers.n_frames(path) == 3
    for k in range(3):
        image = readers.read(path, frame=k)
        assert image.config["frame"] == k
        assert image.config["header"]["FrameIndex"] == k
        rows, cols = np.nonzero(image.polar == 250)
        assert rows.tolist() == [10 + 20 * k] and cols.tolist() == [47 - k]
    images = list(readers.read_frames(path))
    assert [im.config["frame"] for im in images] == [0, 1, 2]
    assert np.array_equal(images[2].polar, readers.read(path, 2).polar)


def test_aris_reads_one_frame_with_seeks(tmp_path, monkeypatch):
    # 200 frames; reading the last must read the two headers and one frame, not the file.
    path = write_aris(tmp_path / "long.aris", [({}, [])] * 200)
    read_bytes = []
    real_open = open

    class Counting:
        def __init__(self, *a, **k):
            self._f = real_open(*a, **k)

        def read(self, n=-1):
            data = self._f.read(n)
            read_bytes.append(len(data))
            return data

        def __getattr__(self, name):
            return getattr(self._f, name)

    from sonarsim.io.readers import _common

    monkeypatch.setattr(_common, "open", Counting, raising=False)
    image = readers.read(path, 199)
    assert image.config["frame"] == 199
    # The file header, the headers of frames 0-199 (frame 199 is good only if those before it
    # are: the rule of the good frames; frame 0's is read twice, for the frame size and when
    # checked, and frame 199's when checked and when read) and frame 199's samples: no other
    # frame's samples.
    assert 0 < sum(read_bytes) <= 1024 + 202 * 1024 + 100 * 48 < 200 * 100 * 48


def test_aris_frame_out_of_range_names_valid_range(tmp_path):
    path = write_aris(tmp_path / "few.aris", [({}, [])] * 3)
    with pytest.raises(RecordingError, match=r"0 to 2") as err:
        readers.read(path, 3)
    assert str(path) in str(err.value)
    with pytest.raises(RecordingError, match=r"0 to 2"):
        readers.read(path, -1)
    with pytest.raises(TypeError):
        readers.read(path, 1.0)


@pytest.mark.parametrize(
    "cut, where",
    [
        (500, "file header"),  # inside the file header
        (1024 + 500, "frame 0"),  # inside frame 0's header
        (1024 + 1024 + 50, "frame 0"),  # inside frame 0's samples
    ],
)
def test_aris_truncated_first_frame(tmp_path, cut, where):
    full = write_aris(tmp_path / "full.aris", [({}, [])] * 2).read_bytes()
    path = tmp_path / "cut.aris"
    path.write_bytes(full[:cut])
    with pytest.raises(RecordingError, match="truncated|SamplesPerBeam") as err:
        readers.read(path)
    message = str(err.value)
    assert str(path) in message and where in message
    with pytest.raises(RecordingError):
        readers.n_frames(path)


@pytest.mark.parametrize("into_last", [300, 1024 + 30], ids=["in-header", "in-samples"])
def test_aris_truncated_last_frame(tmp_path, into_last):
    frame = 1024 + 100 * 48
    full = write_aris(tmp_path / "full.aris", [({}, [(5, 5)])] * 3).read_bytes()
    path = tmp_path / "cut.aris"
    path.write_bytes(full[: 1024 + 2 * frame + into_last])
    assert readers.n_frames(path) == 2
    assert readers.read(path, 1).polar.shape == (100, 48)
    part = "header" if into_last < 1024 else "samples"
    with pytest.raises(RecordingError, match=f"truncated.*{part}") as err:
        readers.read(path, 2)
    assert "frame 2" in str(err.value) and str(path) in str(err.value)
    frames = readers.read_frames(path)
    assert next(frames).config["frame"] == 0
    assert next(frames).config["frame"] == 1
    with pytest.raises(RecordingError, match="truncated"):
        next(frames)


def test_aris_corrupt_signatures(tmp_path):
    data = bytearray(write_aris(tmp_path / "ok.aris", [({}, [])] * 2).read_bytes())
    bad_file = bytearray(data)
    struct.pack_into("<I", bad_file, 0, 0x05464445)
    path = tmp_path / "badfile.aris"
    path.write_bytes(bytes(bad_file))
    with pytest.raises(RecordingError, match="not a recognised sonar recording") as err:
        readers.read(path)
    assert str(path) in str(err.value)
    # A corrupt frame header (frame 1): frame 0 still reads, frame 1 names field and frame.
    bad_frame = bytearray(data)
    struct.pack_into("<I", bad_frame, 1024 + (1024 + 4800) + 12, 0xDEADBEEF)
    path = tmp_path / "badframe.aris"
    path.write_bytes(bytes(bad_frame))
    assert readers.read(path, 0).polar.shape == (100, 48)
    with pytest.raises(RecordingError, match=r"frame 1: Version: signature 0xdeadbeef"):
        readers.read(path, 1)
    # Older DIDSON files.
    didson = bytearray(data)
    didson[:4] = b"DDF\x04"
    path = tmp_path / "didson.ddf"
    path.write_bytes(bytes(didson))
    with pytest.raises(RecordingError, match="DIDSON"):
        readers.read(path)


@pytest.mark.parametrize(
    "kw, field",
    [
        ({"ping_mode": 0}, "PingMode"),  # zero beams: no known ping mode gives 0 beams
        ({"ping_mode": 13}, "PingMode"),
        ({"samples_per_beam": 0}, "SamplesPerBeam"),
        ({"samples_per_beam": 10**6}, "SamplesPerBeam"),  # does not fit the file
        ({"sample_period_us": 0}, "SamplePeriod"),
        ({"sound_speed": 0.0}, "SoundSpeed"),
        ({"sound_speed": float("nan")}, "SoundSpeed"),
        ({"system_type": 7}, "TheSystemType"),
        ({"large_lens": 3}, "LargeLens"),
        ({"system_type": 1, "large_lens": 1, "ping_mode": 9}, "PingMode"),  # no ARIS 3000 telephoto table
        ({"system_type": 2, "ping_mode": 3}, "PingMode"),  # no ARIS 1200 x 96 table
        ({"reordered": 0}, "ReorderedSamples"),
        # Issue 11: values no ARIS produces, which read "successfully" as windows of 6e9 m.
        ({"sample_period_us": 0xFFFFFFFF}, "SamplePeriod"),
        ({"sample_period_us": 0x7FFFFFFF}, "SamplePeriod"),
        ({"sample_period_us": 401}, "SamplePeriod"),
        ({"start_delay_us": 0xFFFFFFFF}, "SampleStartDelay"),
        ({"start_delay_us": 240_001}, "SampleStartDelay"),
        ({"samples_per_beam": 16_001}, "SamplesPerBeam"),
        ({"sound_speed": 1e30}, "SoundSpeed"),
    ],
)
def test_aris_impossible_header_values(tmp_path, kw, field):
    header = aris_frame_header(**kw)
    n_beams = PING_MODE_BEAMS.get(kw.get("ping_mode", 1), 48)
    path = tmp_path / "bad.aris"
    path.write_bytes(aris_file_header() + header + bytes(100 * n_beams))
    with pytest.raises(RecordingError) as err:
        readers.read(path)
    message = str(err.value)
    assert str(path) in message and "frame 0" in message and field in message
    assert isinstance(err.value, SonarsimError) and err.value.field == field


def test_aris_limits_message_names_value_and_allowed_range(tmp_path):
    path = tmp_path / "far.aris"
    path.write_bytes(aris_file_header() + aris_frame_header(sample_period_us=0xFFFFFFFF) + bytes(4800))
    with pytest.raises(RecordingError) as err:
        readers.read(path)
    assert str(err.value) == (
        f"{path}: frame 0: SamplePeriod: 4294967295 us is outside the allowed 1 to 400 us "
        "(ARIS sonars use 4-100 us)"
    )


def test_aris_limits_accept_their_bounds(tmp_path):
    # The extremes of every limit still read (a limit must not refuse what it names allowed).
    path = write_aris(tmp_path / "edge.aris", [({"sample_period_us": 400, "start_delay_us": 240_000,
                                                  "sound_speed": 2000.0, "samples_per_beam": 100}, [])])
    image = readers.read(path)
    assert image.sonar.range_min_m == pytest.approx(240.0)
    assert image.sonar.range_max_m == pytest.approx(240.0 + 100 * 0.4)
    path = write_aris(tmp_path / "near.aris", [({"sample_period_us": 1, "start_delay_us": 0}, [])])
    assert readers.read(path).sonar.range_max_m == pytest.approx(100 * 1e-6 * 750.0)


def test_aris_window_beyond_any_aris_is_refused(tmp_path):
    # Every field within its limits, but 2000 samples of 400 us at 2000 m/s reach 800 m.
    path = write_aris(tmp_path / "long.aris", [({"sample_period_us": 400, "sound_speed": 2000.0,
                                                  "samples_per_beam": 2000}, [])])
    with pytest.raises(RecordingError) as err:
        readers.read(path)
    assert err.value.field == "SamplePeriod" and err.value.where == "frame 0"
    assert "range window of 2-802 m" in str(err.value) and "no farther than 400 m" in str(err.value)
    assert "SamplesPerBeam 2000 x SamplePeriod 400 us" in str(err.value)


def test_aris_frame_beyond_the_memory_budget_is_refused(tmp_path):
    from sonarsim.core.memory import set_memory_budget

    path = write_aris(tmp_path / "big.aris", [({"samples_per_beam": 2000}, [])])
    set_memory_budget(2000 * 48 * (5 + 160) - 1)  # a byte short: samples, float32 image, 40 images
    try:
        with pytest.raises(RecordingError, match=r"frame 0: SamplesPerBeam: .*memory budget"):
            readers.read(path)
        with pytest.raises(RecordingError, match="memory budget"):
            list(readers.read_frames(path))
        set_memory_budget(2000 * 48 * (5 + 160))
        assert readers.read(path).polar.shape == (2000, 48)
    finally:
        set_memory_budget(None)


def test_aris_frames_of_different_sizes_are_refused(tmp_path):
    out = bytearray(aris_file_header())
    out += aris_frame_header(index=0) + aris_samples(100, 48)
    out += aris_frame_header(index=1, ping_mode=6, system_type=1) + aris_samples(100, 48)
    path = tmp_path / "mixed.aris"
    path.write_bytes(bytes(out))
    assert readers.read(path, 0).polar.shape == (100, 48)
    with pytest.raises(RecordingError, match=r"frame 1: PingMode: gives 64 beams, frame 0 48"):
        readers.read(path, 1)


def test_aris_file_without_frames(tmp_path):
    path = tmp_path / "empty.aris"
    path.write_bytes(aris_file_header())
    assert readers.n_frames(path) == 0
    with pytest.raises(RecordingError, match="no frames"):
        readers.read(path)
    # Iteration fails as read(0) does, rather than yielding nothing (issue 11).
    with pytest.raises(RecordingError, match="no frames"):
        list(readers.read_frames(path))


# ------------------------------------------------------------------------------------------
# Oculus, synthetic
# ------------------------------------------------------------------------------------------


def test_oculus_bright_sample_lands_in_left_most_first_column(tmp_path):
    # Bearings ascend (port first, as the sonar sends them): file column b stays column b.
    n_ranges, n_beams = 50, 16
    img = bright_image(n_ranges, n_beams, [(30, 3, 200)])
    path = tmp_path / "one.raw"
    path.write_bytes(oculus_message(img, ascending_bearings(n_beams)))
    image = readers.read(path)
    assert image.polar.dtype == np.float32 and image.polar.shape == (n_ranges, n_beams)
    rows, cols = np.nonzero(image.polar == 200)
    assert rows.tolist() == [30] and cols.tolist() == [3]
    # Positive bearing = starboard -> azimuth = -bearing, left-most (positive) first.
    np.testing.assert_allclose(image.azimuth_deg, -ascending_bearings(n_beams) / 100.0)
    assert image.azimuth_deg[0] == pytest.approx(30.0)
    assert image.config["format"] == "oculus" and image.config["frame"] == 0
    assert image.components["total"] is image.polar and image.rays is None


def test_oculus_descending_bearings_are_flipped(tmp_path):
    n_ranges, n_beams = 20, 8
    img = bright_image(n_ranges, n_beams, [(7, 1, 99)])
    path = tmp_path / "desc.raw"
    path.write_bytes(oculus_message(img, ascending_bearings(n_beams)[::-1]))
    image = readers.read(path)
    rows, cols = np.nonzero(image.polar == 99)
    assert rows.tolist() == [7] and cols.tolist() == [n_beams - 1 - 1]
    assert np.all(np.diff(image.azimuth_deg) < 0)
    assert image.azimuth_deg[0] == pytest.approx(30.0)


def test_oculus_range_axis(tmp_path):
    img = bright_image(40, 8, [])
    path = tmp_path / "r.raw"
    path.write_bytes(oculus_message(img, ascending_bearings(8), range_resolution=0.005))
    image = readers.read(path)
    s = image.sonar
    assert s.range_min_m == 0.0 and s.range_max_m == pytest.approx(0.2)
    assert s.n_range_bins == 40
    np.testing.assert_allclose(image.range_m, (np.arange(40) + 0.5) * 0.005)
    assert s.frequency_khz == pytest.approx(2100.0)
    assert s.elevation_fov_deg == 12.0


def test_oculus_messages_back_to_back_and_other_messages_skipped(tmp_path):
    n_ranges, n_beams = 30, 8
    pings = [oculus_message(bright_image(n_ranges, n_beams, [(5 + k, k, 100 + k)]), ascending_bearings(n_beams), ping_id=10 + k) for k in range(3)]
    log = oculus_message(bright_image(2, 2, []), ascending_bearings(2), msg_id=0x80)
    path = tmp_path / "many.raw"
    path.write_bytes(pings[0] + log + pings[1] + pings[2])
    assert readers.n_frames(path) == 3
    for k in range(3):
        image = readers.read(path, k)
        assert image.config["header"]["pingId"] == 10 + k
        rows, cols = np.nonzero(image.polar == 100 + k)
        assert rows.tolist() == [5 + k] and cols.tolist() == [k]
    assert [im.config["frame"] for im in readers.read_frames(path)] == [0, 1, 2]
    with pytest.raises(RecordingError, match=r"0 to 2") as err:
        readers.read(path, 3)
    assert str(path) in str(err.value)


@pytest.mark.parametrize("data_size, top", [(1, 60000), (2, 2**24 - 1), (3, 2**24 + 2)])
def test_oculus_wide_data(tmp_path, data_size, top):
    img = bright_image(12, 6, [(4, 2, top), (0, 0, 300)])
    path = tmp_path / "wide.raw"
    path.write_bytes(oculus_message(img, ascending_bearings(6), data_size=data_size))
    image = readers.read(path)
    assert image.polar[4, 2] == np.float32(top) and image.polar[0, 0] == 300 and image.polar[1, 1] == 5
    assert image.config["header"]["bits_per_value"] == 8 * (data_size + 1)


def test_oculus_gain_words_are_stripped(tmp_path):
    img = bright_image(10, 4, [(3, 2, 77)])
    path = tmp_path / "gain.raw"
    path.write_bytes(oculus_message(img, ascending_bearings(4), send_gain=True))
    image = readers.read(path)
    assert image.polar.shape == (10, 4)
    assert image.polar[3, 2] == 77 and np.count_nonzero(image.polar == 77) == 1
    assert image.config["header"]["rowGainsRaw"] == list(range(1, 11))


def test_oculus_version_2(tmp_path):
    img = bright_image(25, 10, [(20, 9, 222)])
    path = tmp_path / "v2.raw"
    path.write_bytes(oculus_message(img, ascending_bearings(10, 65.0), version=2, frequency=1.2e6, master_mode=1))
    image = readers.read(path)
    rows, cols = np.nonzero(image.polar == 222)
    assert rows.tolist() == [20] and cols.tolist() == [9]
    assert image.azimuth_deg[0] == pytest.approx(65.0)
    h = image.config["header"]
    assert h["msgVersion"] == 2 and h["heading"] == 10.0 and h["extFlags"] == 0x200
    assert image.sonar.elevation_fov_deg == 20.0  # 1.2 MHz, low-frequency mode


def test_oculus_unknown_version_is_refused(tmp_path):
    path = tmp_path / "v3.raw"
    path.write_bytes(oculus_message(bright_image(5, 4, []), ascending_bearings(4), version=3))
    with pytest.raises(RecordingError, match="version 3 is not supported"):
        readers.read(path)


def test_oculus_elevation_assumptions():
    assert elevation_fov_deg(2.1e6, 2) == 12.0  # M1200d high frequency
    assert elevation_fov_deg(1.2e6, 1) == 20.0  # M1200d low frequency
    assert elevation_fov_deg(1.2e6, 2) == 12.0  # M750d high frequency
    assert elevation_fov_deg(7.5e5, 1) == 20.0  # M750d low frequency


@pytest.mark.parametrize(
    "kw, field",
    [
        ({"image_size": 999}, "imageSize"),
        ({"data_size": 5}, "dataSize"),
        ({"range_resolution": 0.0}, "rangeResolution"),
        ({"range_resolution": float("nan")}, "rangeResolution"),
        # Issue 11: values no Oculus produces.
        ({"range_resolution": 1e-300}, "rangeResolution"),
        ({"range_resolution": 1e300}, "rangeResolution"),
        ({"range_resolution": -0.01}, "rangeResolution"),
        ({"frequency": float("nan")}, "frequency"),
        ({"frequency": 0.0}, "frequency"),
        ({"frequency": 1e300}, "frequency"),
    ],
)
def test_oculus_impossible_header_values(tmp_path, kw, field):
    n_beams = 4
    data_size = kw.pop("data_size", 0)
    msg = bytearray(oculus_message(bright_image(6, n_beams, []), ascending_bearings(n_beams), **kw))
    if data_size:
        msg[97] = data_size
    path = tmp_path / "bad.raw"
    path.write_bytes(bytes(msg))
    with pytest.raises(RecordingError) as err:
        readers.read(path)
    message = str(err.value)
    assert str(path) in message and "ping 0" in message and field in message


def test_oculus_limits_message_names_value_and_allowed_range(tmp_path):
    path = tmp_path / "tiny.raw"
    path.write_bytes(oculus_message(bright_image(6, 4, []), ascending_bearings(4), range_resolution=1e-300))
    with pytest.raises(RecordingError) as err:
        readers.read(path)
    assert str(err.value) == (
        f"{path}: ping 0 (message 0, byte 0): rangeResolution: 1e-300 m is outside the allowed "
        "5e-05 to 1 m (Oculus range lines are a few millimetres to decimetres long)"
    )


def test_oculus_window_beyond_any_oculus_is_refused(tmp_path):
    # 600 lines of 0.9 m: each field plausible, the 540 m window not.
    path = tmp_path / "far.raw"
    path.write_bytes(oculus_message(bright_image(600, 4, []), ascending_bearings(4), range_resolution=0.9))
    with pytest.raises(RecordingError, match=r"rangeResolution: gives a range window of 0-540 m "
                       r"\(nRanges 600 x rangeResolution 0.9 m\), but these sonars record no farther "
                       r"than 500 m"):
        readers.read(path)
    path.write_bytes(oculus_message(bright_image(500, 4, []), ascending_bearings(4), range_resolution=0.9))
    assert readers.read(path).sonar.range_max_m == pytest.approx(450.0)


def test_oculus_too_many_beams(tmp_path):
    msg = bytearray(oculus_message(bright_image(6, 4, []), ascending_bearings(4)))
    struct.pack_into("<H", msg, 108, 4096)
    path = tmp_path / "beams.raw"
    path.write_bytes(bytes(msg))
    with pytest.raises(RecordingError, match=r"nBeams: 4096 is outside the allowed 1 to 2048 \(Oculus sonars form 256 or 512 beams\)"):
        readers.read(path)


def test_oculus_bearing_table_out_of_order_is_refused(tmp_path):
    # Previously sorted into place; a real table ascends or descends, so this one is corrupt.
    path = tmp_path / "shuffled.raw"
    path.write_bytes(oculus_message(bright_image(6, 4, []), np.array([-100, 100, 0, 200])))
    with pytest.raises(RecordingError) as err:
        readers.read(path)
    assert err.value.field == "bearings"
    assert "beams 1 and 2 (1 and 0 deg) reverse the order of the table" in str(err.value)


@pytest.mark.parametrize("bearings", [[-3000, -1000, 1000, 8900], [8950]], ids=["wide-last-gap", "lone-beam"])
def test_oculus_fan_edges_beyond_90_deg_are_refused(tmp_path, bearings):
    # Found by fuzzing: centres inside +-90 deg passed, the fan's outer edge (half a spacing
    # beyond, here 128.5 deg; a lone beam is 1 deg wide) did not, and the ping ended in "gives
    # an impossible sonar" from SonarConfig instead of naming the bearings.
    path = tmp_path / "wide.raw"
    path.write_bytes(oculus_message(bright_image(6, len(bearings), []), np.array(bearings)))
    with pytest.raises(RecordingError, match=r"ping 0 .*: bearings: the fan's outer beam edges lie at bearings") as err:
        readers.read(path)
    assert "impossible sonar" not in str(err.value)
    if len(bearings) > 1:
        assert "bearings -40 and 128.5 deg" in str(err.value)
    ok = [-3000, -1000, 1000, 3000] if len(bearings) > 1 else [8900]
    path.write_bytes(oculus_message(bright_image(6, len(ok), []), np.array(ok)))
    assert readers.read(path).polar.shape == (6, len(ok))


def test_oculus_ping_beyond_the_memory_budget_is_refused(tmp_path):
    from sonarsim.core.memory import set_memory_budget

    path = tmp_path / "big.raw"
    path.write_bytes(oculus_message(bright_image(300, 64, []), ascending_bearings(64)))
    set_memory_budget(300 * 64 * (8 + 160) - 1)
    try:
        with pytest.raises(RecordingError, match=r"ping 0 .*: nRanges: .*memory budget"):
            readers.read(path)
    finally:
        set_memory_budget(None)
    assert readers.read(path).polar.shape == (300, 64)


def test_oculus_zero_beams(tmp_path):
    msg = bytearray(oculus_message(bright_image(6, 4, []), ascending_bearings(4)))
    struct.pack_into("<H", msg, 108, 0)
    path = tmp_path / "nobeams.raw"
    path.write_bytes(bytes(msg))
    with pytest.raises(RecordingError, match=r"ping 0 .*: nBeams: is 0"):
        readers.read(path)


def test_oculus_duplicate_bearings(tmp_path):
    path = tmp_path / "dup.raw"
    path.write_bytes(oculus_message(bright_image(6, 4, []), np.array([-100, 0, 0, 100])))
    with pytest.raises(RecordingError, match="bearings"):
        readers.read(path)


@pytest.mark.parametrize("cut", [10, 100, -5], ids=["in-header", "in-ping-fields", "in-image"])
def test_oculus_truncated_single_message(tmp_path, cut):
    msg = oculus_message(bright_image(30, 8, []), ascending_bearings(8))
    assert len(msg) > 138 + 8 * 30  # the image starts after the bearings: -5 cuts into it
    path = tmp_path / "cut.raw"
    path.write_bytes(msg[:cut])
    with pytest.raises(RecordingError, match="truncated") as err:
        readers.read(path)
    assert str(path) in str(err.value) and "message 0" in str(err.value)


def test_oculus_truncated_last_message(tmp_path):
    msgs = [oculus_message(bright_image(30, 8, [(k, k, 50)]), ascending_bearings(8), ping_id=k) for k in range(3)]
    path = tmp_path / "cut.raw"
    path.write_bytes(msgs[0] + msgs[1] + msgs[2][:-7])
    assert readers.n_frames(path) == 2
    assert readers.read(path, 1).config["header"]["pingId"] == 1
    with pytest.raises(RecordingError, match="truncated") as err:
        readers.read(path, 2)
    assert "message 2" in str(err.value)
    frames = readers.read_frames(path)
    assert [next(frames).config["frame"] for _ in range(2)] == [0, 1]
    with pytest.raises(RecordingError, match="truncated"):
        next(frames)


def test_oculus_corrupt_second_header(tmp_path):
    msgs = [oculus_message(bright_image(10, 4, []), ascending_bearings(4), ping_id=k) for k in range(2)]
    bad = bytearray(msgs[1])
    bad[0:2] = b"XX"
    path = tmp_path / "corrupt.raw"
    path.write_bytes(msgs[0] + bytes(bad))
    assert readers.read(path, 0).polar.shape == (10, 4)  # indexed lazily: ping 0 is fine
    # The corrupt header ends the good pings (issue 21: n_frames used to refuse the file while
    # read and read_frames gave ping 0); every reader says so alike.
    assert readers.n_frames(path) == 1
    with readers.open_recording(path) as recording:
        assert recording.n_frames == 1
        assert recording.damage.field == "oculusId" and recording.damage.where.startswith("message 1 (byte ")
    with pytest.raises(RecordingError, match=r"message 1 \(byte \d+\): oculusId"):
        readers.read(path, 1)
    frames = readers.read_frames(path)
    assert next(frames).config["frame"] == 0
    with pytest.raises(RecordingError, match=r"message 1 \(byte \d+\): oculusId"):
        next(frames)


def test_oculus_file_without_pings(tmp_path):
    path = tmp_path / "logs.raw"
    path.write_bytes(oculus_message(bright_image(2, 2, []), ascending_bearings(2), msg_id=0x80))
    assert readers.n_frames(path) == 0
    with pytest.raises(RecordingError, match="no simple ping result"):
        readers.read(path)
    # Iteration fails as read(0) does, rather than yielding nothing (issue 11: a changed
    # message id made read raise but read_frames stop silently).
    with pytest.raises(RecordingError, match="no simple ping result"):
        list(readers.read_frames(path))


# ------------------------------------------------------------------------------------------
# Foreign files
# ------------------------------------------------------------------------------------------


def test_foreign_files(tmp_path):
    png = tmp_path / "picture.aris"  # the suffix must not matter
    Image.fromarray(np.zeros((4, 4), np.uint8)).save(png, format="PNG")
    with pytest.raises(RecordingError, match="PNG") as err:
        readers.read(png)
    assert str(png) in str(err.value)

    noise = tmp_path / "noise.raw"
    noise.write_bytes(np.random.default_rng(1).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    assert noise.read_bytes()[:2] != b"SO"
    with pytest.raises(RecordingError, match="not a recognised sonar recording") as err:
        readers.read(noise)
    assert str(noise) in str(err.value)
    with pytest.raises(RecordingError):
        readers.read_frames(noise)  # raises at once, not at the first next()
    with pytest.raises(RecordingError):
        readers.n_frames(noise)

    empty = tmp_path / "empty.aris"
    empty.write_bytes(b"")
    with pytest.raises(RecordingError, match="empty"):
        readers.read(empty)

    with pytest.raises(FileNotFoundError):
        readers.read(tmp_path / "missing.aris")


def test_format_is_recognised_by_content(tmp_path):
    aris = write_aris(tmp_path / "sonar.raw", [({}, [])])  # an ARIS file named .raw
    oculus = tmp_path / "sonar.aris"
    oculus.write_bytes(oculus_message(bright_image(4, 4, []), ascending_bearings(4)))
    assert readers.detect_format(aris) == "aris" and readers.read(aris).config["format"] == "aris"
    assert readers.detect_format(oculus) == "oculus"
    assert readers.read(oculus).config["format"] == "oculus"


def test_header_is_json_serialisable(tmp_path):
    path = write_aris(tmp_path / "j.aris", [({}, [(1, 1)])])
    image = readers.read(path)
    image.save_npz(tmp_path / "j.npz")  # the config (with the header) goes through JSON
    from sonarsim.io.output import read_npz

    arrays, config = read_npz(tmp_path / "j.npz")
    assert config["header"]["PingMode"] == 1 and arrays["polar"].shape == (100, 48)


# ------------------------------------------------------------------------------------------
# Real recordings
# ------------------------------------------------------------------------------------------


@needs_data
def test_real_aris_sample():
    assert readers.n_frames(ARIS_SAMPLE) == 6
    image = readers.read(ARIS_SAMPLE, 0)
    h = image.config["header"]
    assert image.polar.shape == (2000, 48)
    assert h["model"] == "ARIS 1200" and h["lens"] == "telephoto"
    # data/README.md: window 3.30-23.40 m (SampleStartDelay, SamplePeriod, SoundSpeed).
    assert image.sonar.range_min_m == pytest.approx(3.30, abs=0.005)
    assert image.sonar.range_max_m == pytest.approx(23.40, abs=0.005)
    np.testing.assert_allclose(image.azimuth_deg, aris_beam_angles_deg("ARIS-telephoto", 48))
    assert 7.0 < image.azimuth_deg[0] < 7.7  # the telephoto lens: about 15 deg wide
    # LargeLens 1 in the sample: the telephoto lens's aperture and preset, not 14 deg.
    assert h["LargeLens"] == 1 and image.sonar.elevation_fov_deg == 3.0
    assert image.sonar.preset == "aris1200-48-telephoto"
    frames = list(readers.read_frames(ARIS_SAMPLE))
    assert len(frames) == 6 and [f.config["header"]["FrameIndex"] for f in frames] == list(range(6))


@needs_data
@pytest.mark.parametrize("frame", range(6))
def test_real_aris_sample_order_gives_a_continuous_sea_bed(frame):
    # Sample-major reading: neighbouring beams see the same sea bed, so their range profiles
    # (smoothed over 51 samples) correlate almost perfectly. Read beam-major they do not.
    polar = readers.read(ARIS_SAMPLE, frame).polar.astype(float)
    kernel = np.ones(51) / 51
    smooth = np.stack([np.convolve(polar[:, j], kernel, mode="valid") for j in range(48)], axis=1)
    corr = [np.corrcoef(smooth[:, j], smooth[:, j + 1])[0, 1] for j in range(47)]
    assert min(corr) > 0.9
    # The echo falls off with range across the whole fan (a band over all beams).
    near, far = polar[:200].mean(axis=0), polar[-200:].mean(axis=0)
    assert np.all(near > far)


@needs_data
def test_real_oculus_pings():
    assert readers.n_frames(OCULUS_ONE) == 1
    assert readers.n_frames(OCULUS_THREE) == 3
    image = readers.read(OCULUS_ONE)
    h = image.config["header"]
    assert image.polar.shape == (703, 256)
    assert h["rangeResolution"] == pytest.approx(0.002842, abs=1e-6)
    assert image.sonar.range_max_m == pytest.approx(703 * 0.0028422, rel=1e-4)
    bearings = np.asarray(h["bearings_deg"])
    assert np.all(np.abs(bearings) <= 30.0) and bearings[0] == -30.0 and bearings[-1] == 30.0
    # Positive bearing = starboard, so azimuth = -bearing and the first column is port (+30).
    np.testing.assert_allclose(image.azimuth_deg, -bearings)
    assert image.sonar.elevation_fov_deg == 12.0 and image.sonar.frequency_khz == pytest.approx(2098.88, abs=0.01)
    # Floor band onset: first range beyond 0.1 m where the centre beams exceed 80.
    centre = image.polar[:, 118:138].mean(axis=1)
    onset = image.range_m[np.argmax((centre > 80) & (image.range_m > 0.1))]
    assert onset == pytest.approx(0.75, abs=0.08)
    pings = list(readers.read_frames(OCULUS_THREE))
    assert [p.config["header"]["pingId"] for p in pings] == [415323, 415324, 415325]
    assert np.array_equal(pings[0].polar, image.polar)
    assert not np.array_equal(pings[1].polar, pings[0].polar)


# ------------------------------------------------------------------------------------------
# sonarsim show
# ------------------------------------------------------------------------------------------


def show_args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="sonarsim")
    sub = parser.add_subparsers(dest="command")
    returned = add_show_parser(sub)
    assert isinstance(returned, argparse.ArgumentParser)
    args = parser.parse_args(["show", *argv])
    assert args.func is cmd_show
    return args


def test_show_writes_polar_and_fan(tmp_path, capsys):
    path = write_aris(tmp_path / "s.aris", [({}, [(40, 5)]), ({}, [(60, 7)])])
    out = tmp_path / "out" / "nested"
    args = show_args(str(path), "--frame", "1", "--out", str(out))
    assert args.mapping is None and args.gain_db == 0.0  # None: the image's own (linear for a recording)
    args.func(args)
    polar = np.asarray(Image.open(out / "polar.png"))
    fan = np.asarray(Image.open(out / "fan.png"))
    image = readers.read(path, 1)
    # Linear, 0 dB, full scale 255: the polar PNG is the recorded values, far range on top.
    assert np.array_equal(polar, image.polar[::-1].astype(np.uint8))
    assert fan.ndim == 2 and fan.max() > 0
    err = capsys.readouterr().err
    assert "frame 1 of 2" in err and "polar.png" in err


@needs_data
def test_show_real_oculus(tmp_path):
    args = show_args(str(OCULUS_ONE), "--out", str(tmp_path), "--mapping", "db", "--pixel-size", "0.01")
    cmd_show(args)
    fan = np.asarray(Image.open(tmp_path / "fan.png"))
    assert fan.shape[0] == pytest.approx(200, abs=2)  # 2 m at 1 cm per pixel
    assert np.asarray(Image.open(tmp_path / "polar.png")).shape == (703, 256)


def test_show_bad_input(tmp_path):
    path = write_aris(tmp_path / "s.aris", [({}, [])])
    with pytest.raises(RecordingError, match="0 to 0"):
        cmd_show(show_args(str(path), "--frame", "4", "--out", str(tmp_path / "o")))
    assert not (tmp_path / "o" / "polar.png").exists()
    noise = tmp_path / "n.bin"
    noise.write_bytes(b"\x00\x01garbage" * 10)
    with pytest.raises(RecordingError):
        cmd_show(show_args(str(noise), "--out", str(tmp_path / "o")))
    with pytest.raises(SystemExit):
        show_args(str(path), "--out", str(tmp_path), "--pixel-size", "-1")
