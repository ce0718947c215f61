"""Tests for the recorded-run frame stream (corpuscle.io, docs/frame_format.md)."""

import json
import math
import mmap
import struct
import warnings
import zlib

import numpy as np
import pytest

import corpuscle
from corpuscle.io import FrameStreamError, FrameWriter, Run, TruncatedRunWarning


# ---- helpers ---------------------------------------------------------------------------

HEADER = {"scene": "magic_8_ball", "dim": 3, "backend": "cpu",
          "parameters": {"h": 0.05, "gamma": 7}, "container": {"sphere": {"radius": 0.15}}}


def frame_data(k, n_fluid=10, n_ghost=3):
    """Deterministic contents of frame k: fields, groups, rigid, diagnostics."""
    rng = np.random.default_rng(k)
    fields = {"position": rng.random((n_fluid, 3), dtype=np.float32),
              "density": rng.random(n_fluid, dtype=np.float32) + 1000,
              "ghost_position": rng.random((n_ghost, 3), dtype=np.float32)}
    rigid = {"die": {"position": rng.random(3), "orientation": np.array([1.0, 0, 0, 0])}}
    return dict(step=10 * k, time=0.01 * k, dt=1e-4 * (k + 1), fields=fields,
                groups={"ghost_position": "ghost"}, rigid=rigid,
                diagnostics={"kinetic_energy": 0.5 * k, "step_squared": float(k * k)})


def write_run(path, n_frames=4, **sizes):
    """A small run of n_frames frames; returns the frames' contents."""
    frames = [frame_data(k, **sizes) for k in range(n_frames)]
    with FrameWriter(path, HEADER) as w:
        for f in frames:
            w.write_frame(**f)
    return frames


def parse_layout(path):
    """Parse a run file by docs/frame_format.md alone, independently of the reader."""
    raw = path.read_bytes()
    magic, version, flags, json_len, reserved, header_crc = struct.unpack_from("<8sIIQII", raw, 0)
    first = -(-(32 + json_len) // 64) * 64
    out = dict(raw=raw, magic=magic, version=version, flags=flags, reserved=reserved,
               header_crc=header_crc, json_len=json_len, first=first,
               header=json.loads(raw[32:32 + json_len].decode()), frames=[])
    # walk the frames by their lengths
    off = first
    while off + 64 <= len(raw):
        (fmagic, frame_len, index, step, time, dt, table_len, kind, res, data_crc,
         head_crc) = struct.unpack_from("<8sQQqddIHHII", raw, off)
        if off + frame_len > len(raw):
            break
        out["frames"].append(dict(
            offset=off, magic=fmagic, frame_len=frame_len, index=index, step=step, time=time,
            dt=dt, table_len=table_len, kind=kind, reserved=res, data_crc=data_crc,
            head_crc=head_crc, data_start=off + (-(-(64 + table_len) // 64) * 64),
            table=json.loads(raw[off + 64:off + 64 + table_len].decode())))
        off += frame_len
    out["end"] = off
    return out


def flipped(raw, pos):
    """A copy of raw with the byte at pos inverted."""
    data = bytearray(raw)
    data[pos] ^= 0xFF
    return bytes(data)


def assert_frame_equals(frame, expected):
    """Every field, rigid array and diagnostic of frame equals expected, dtype included."""
    assert frame.step == expected["step"]
    assert frame.time == expected["time"] and frame.dt == expected["dt"]
    assert list(frame.fields) == list(expected["fields"])
    for name, arr in expected["fields"].items():
        assert frame[name].dtype == arr.dtype and frame[name].shape == arr.shape
        np.testing.assert_array_equal(frame[name], arr)
    for body, state in expected["rigid"].items():
        for key, arr in state.items():
            np.testing.assert_array_equal(frame.rigid[body][key], arr)
    assert frame.diagnostics == expected["diagnostics"]


def open_quietly(path):
    """Open a run, failing on any warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return corpuscle.open(path)


# ---- round trips -----------------------------------------------------------------------

def test_round_trip_keeps_values_dtypes_and_shapes_of_every_field_kind(tmp_path):
    # bool, integers, floats of three widths, complex; 1-D, 2-D and 3-D
    n = 7
    rng = np.random.default_rng(1)
    fields = {"position": rng.random((n, 3), dtype=np.float32),
              "density": rng.random(n, dtype=np.float32),
              "pressure": rng.random(n),                                   # float64
              "cell": rng.integers(-2**31, 2**31, n, dtype=np.int32),
              "color": rng.integers(0, 256, (n, 4), dtype=np.uint8),
              "id": np.arange(n, dtype=np.int64).reshape(n, 1),
              "active": rng.random(n) > 0.5,
              "half": rng.random(n).astype(np.float16),
              "phase": (rng.random(n) + 1j * rng.random(n)).astype(np.complex64),
              "stress": rng.random((n, 3, 3), dtype=np.float32),
              "strided": rng.random((n, 6))[:, ::2]}                       # non-contiguous input
    # one frame with every field kind, read back field by field
    path = tmp_path / "run.cps"
    with FrameWriter(path, HEADER) as w:
        w.write_frame(5, 0.25, 1e-3, fields)
    with corpuscle.open(path) as run:
        frame = run[0]
        assert list(frame.fields) == list(fields)
        for name, arr in fields.items():
            assert frame[name].dtype == arr.dtype, name
            assert frame[name].shape == arr.shape, name
            np.testing.assert_array_equal(frame[name], arr)
        assert (frame.index, frame.step, frame.time, frame.dt, frame.kind) == (0, 5, 0.25, 1e-3, "frame")


def test_big_endian_input_reads_back_as_little_endian_with_equal_values(tmp_path):
    # the file is little-endian whatever the input's byte order
    values = np.arange(12, dtype=">f8").reshape(4, 3)
    path = tmp_path / "run.cps"
    with FrameWriter(path, {}) as w:
        w.write_frame(0, 0.0, 0.1, {"x": values})
    with corpuscle.open(path) as run:
        assert run[0]["x"].dtype == np.dtype("<f8")
        np.testing.assert_array_equal(run[0]["x"], values)


def test_header_round_trips_with_numpy_values_and_version(tmp_path):
    path = tmp_path / "run.cps"
    # numpy values become JSON numbers and lists
    header = dict(HEADER, gravity=np.array([0, 0, -9.81]), n=np.int64(3500), h=np.float32(0.5))
    FrameWriter(path, header).close()
    with corpuscle.open(path) as run:
        assert run.header == dict(HEADER, gravity=[0, 0, -9.81], n=3500, h=0.5)
        assert run.version == 1 and len(run) == 0 and run.path == str(path)


def test_groups_with_different_counts_and_an_empty_ghost_group(tmp_path):
    path = tmp_path / "run.cps"
    pos = np.ones((100, 3), np.float32)
    with FrameWriter(path, HEADER) as w:
        # 100 fluid + 17 ghosts; then 0 ghosts; then no ghost group at all
        w.write_frame(0, 0.0, 0.1, {"position": pos, "density": np.ones(100, np.float32),
                                    "ghost_position": np.zeros((17, 3), np.float32),
                                    "ghost_density": np.zeros(17, np.float32)},
                      groups={"ghost_position": "ghost", "ghost_density": "ghost"})
        w.write_frame(1, 0.1, 0.1, {"position": pos, "ghost_position": np.zeros((0, 3), np.float32)},
                      groups={"ghost_position": "ghost"})
        w.write_frame(2, 0.2, 0.1, {"position": pos[:50]})
    # counts and groups per frame
    with corpuscle.open(path) as run:
        f0, f1, f2 = run
        assert f0.counts == {"fluid": 100, "ghost": 17}
        assert f0.groups == {"position": "fluid", "density": "fluid",
                             "ghost_position": "ghost", "ghost_density": "ghost"}
        assert f0["ghost_position"].shape == (17, 3) and f0["ghost_density"].shape == (17,)
        assert f1.counts == {"fluid": 100, "ghost": 0}
        assert f1["ghost_position"].shape == (0, 3) and f1["ghost_position"].dtype == np.float32
        assert f2.counts == {"fluid": 50} and f2.groups == {"position": "fluid"}


def test_rigid_poses_round_trip_in_3d_and_2d(tmp_path):
    path = tmp_path / "run.cps"
    die = {"position": [0.01, -0.02, 0.03], "orientation": [0.5, 0.5, -0.5, 0.5],
           "velocity": np.array([1.0, 2.0, 3.0], np.float32), "angular_velocity": [0.0, 0.1, 0.2]}
    wing = {"position": np.array([0.3, 0.4]), "orientation": 0.1745}      # 2-D: scalar angle
    with FrameWriter(path, HEADER) as w:
        w.write_frame(0, 0.0, 0.1, {}, rigid={"die": die, "wing": wing})
    # every body array comes back as float64, in write order
    with corpuscle.open(path) as run:
        rigid = run[0].rigid
        assert list(rigid) == ["die", "wing"]
        assert list(rigid["die"]) == ["position", "orientation", "velocity", "angular_velocity"]
        for key, value in die.items():
            assert rigid["die"][key].dtype == np.float64
            np.testing.assert_array_equal(rigid["die"][key], np.asarray(value, np.float64))
        assert rigid["wing"]["position"].shape == (2,)
        assert rigid["wing"]["orientation"].shape == (1,) and rigid["wing"]["orientation"][0] == 0.1745


def test_diagnostics_round_trip_exactly_including_non_finite_values(tmp_path):
    path = tmp_path / "run.cps"
    diag = {"kinetic_energy": 0.1 + 0.2, "die_height": -1e-300, "density_error": math.nan,
            "max_speed": math.inf, "min_pressure": -math.inf, "n_contacts": np.int64(12)}
    with FrameWriter(path, HEADER) as w:
        w.write_frame(0, 0.0, 0.1, {}, diagnostics=diag)
    # exact floats, non-finite values preserved, integers become floats
    with corpuscle.open(path) as run:
        got = run[0].diagnostics
        assert list(got) == list(diag)
        assert got["kinetic_energy"] == 0.1 + 0.2 and got["die_height"] == -1e-300
        assert math.isnan(got["density_error"])
        assert got["max_speed"] == math.inf and got["min_pressure"] == -math.inf
        assert got["n_contacts"] == 12.0 and type(got["n_contacts"]) is float


def test_checkpoint_frames_carry_extra_state_and_their_kind(tmp_path):
    path = tmp_path / "run.cps"
    # a checkpoint between two frames, with velocities, rng state and body velocities
    rng_state = np.array([0x123456789ABCDEF0, 2**64 - 1, 0, 7], dtype=np.uint64)
    seed_bytes = np.frombuffer(b"\x00\xffcorpuscle", dtype=np.uint8)
    with FrameWriter(path, HEADER) as w:
        w.write_frame(**frame_data(0))
        w.write_frame(100, 1.0, 2e-4,
                      {"position": np.ones((5, 3), np.float32), "velocity": np.full((5, 3), 2.0),
                       "rng_state": rng_state, "seed_bytes": seed_bytes},
                      groups={"rng_state": "rng", "seed_bytes": "seed"},
                      rigid={"die": {"position": [0, 0, 0], "orientation": [1, 0, 0, 0],
                                     "velocity": [1, 2, 3], "angular_velocity": [4, 5, 6]}},
                      diagnostics={"dt_next": 2.5e-4, "shake_phase": 0.75}, kind="checkpoint")
        w.write_frame(**frame_data(2))
    # the kind is known from the scan; the extra state comes back exactly
    with corpuscle.open(path) as run:
        assert run.kinds == ["frame", "checkpoint", "frame"]
        cp = run[1]
        assert cp.kind == "checkpoint" and run[0].kind == "frame"
        assert cp.counts == {"fluid": 5, "rng": 4, "seed": 11}
        assert cp["rng_state"].dtype == np.uint64
        np.testing.assert_array_equal(cp["rng_state"], rng_state)
        np.testing.assert_array_equal(cp["seed_bytes"], seed_bytes)
        np.testing.assert_array_equal(cp["velocity"], np.full((5, 3), 2.0))
        np.testing.assert_array_equal(cp.rigid["die"]["angular_velocity"], [4.0, 5.0, 6.0])
        assert cp.diagnostics == {"dt_next": 2.5e-4, "shake_phase": 0.75}


def test_every_frame_reads_back_equal_to_what_was_written(tmp_path):
    path = tmp_path / "run.cps"
    # iteration yields every frame in order, equal to its input
    frames = write_run(path, n_frames=5)
    with corpuscle.open(path) as run:
        assert len(run) == 5
        for k, frame in enumerate(run):
            assert frame.index == k
            assert_frame_equals(frame, frames[k])


# ---- views on the memory map -------------------------------------------------------------

def test_field_arrays_are_aligned_read_only_views_on_the_memory_map(tmp_path):
    path = tmp_path / "run.cps"
    write_run(path, n_frames=3)
    layout = parse_layout(path)
    with corpuscle.open(path) as run:
        frame = run[2]
        arrays = list(frame.fields.values()) + list(frame.rigid["die"].values())
        # the base chain of every array ends in a memoryview of an mmap
        for arr in arrays:
            base = arr
            while isinstance(base, np.ndarray):
                base = base.base
            assert isinstance(base, memoryview) and isinstance(base.obj, mmap.mmap)
        # a byte view of the whole map, to locate arrays in it
        whole = np.frombuffer(base.obj, dtype=np.uint8)
        start = whole.ctypes.data
        table = layout["frames"][2]["table"]
        for spec in table["fields"]:
            arr = frame[spec["name"]]
            # shares memory with the map, at the documented offset, 64-byte aligned
            assert np.shares_memory(arr, whole)
            assert arr.ctypes.data - start == layout["frames"][2]["data_start"] + spec["offset"]
            assert arr.ctypes.data % 64 == 0
            # read-only, and cannot be made writeable
            assert not arr.flags.writeable
            with pytest.raises(ValueError):
                arr[...] = 0
            with pytest.raises(ValueError):
                arr.flags.writeable = True
        # drop the views so close() can unmap at once
        del whole, base, arr, arrays, frame


def test_arrays_stay_valid_after_close_and_closed_run_refuses_frames(tmp_path):
    path = tmp_path / "run.cps"
    frames = write_run(path, n_frames=2)
    # a view taken before close() still reads; new frames are refused
    run = corpuscle.open(path)
    position = run[1]["position"]
    run.close()
    np.testing.assert_array_equal(position, frames[1]["fields"]["position"])
    with pytest.raises(ValueError, match="closed"):
        run[0]
    run.close()


# ---- the documented layout ---------------------------------------------------------------

def test_file_layout_matches_documented_format(tmp_path):
    path = tmp_path / "run.cps"
    frames = write_run(path, n_frames=3)
    with FrameWriter(tmp_path / "cp.cps", HEADER) as w:
        w.write_frame(**frame_data(0), kind="checkpoint")
    # parse by the document, then check each documented field
    lay = parse_layout(path)
    raw = lay["raw"]
    # file header: magic, version, zero flags, JSON, CRC over everything but itself
    assert lay["magic"] == b"\x89CPS\r\n\x1a\n" and lay["version"] == 1
    assert lay["flags"] == 0 and lay["reserved"] == 0 and lay["header"] == HEADER
    assert lay["first"] % 64 == 0 and raw[32 + lay["json_len"]:lay["first"]] == bytes(
        lay["first"] - 32 - lay["json_len"])
    assert lay["header_crc"] == zlib.crc32(raw[32:lay["first"]], zlib.crc32(raw[:28]))
    # frames tile the rest of the file exactly
    assert len(lay["frames"]) == 3 and lay["end"] == len(raw)
    for k, (fr, expected) in enumerate(zip(lay["frames"], frames)):
        off, end = fr["offset"], fr["offset"] + fr["frame_len"]
        assert fr["magic"] == b"CPSFRAME" and fr["index"] == k and fr["kind"] == 0
        assert off % 64 == 0 and fr["frame_len"] % 64 == 0 and fr["reserved"] == 0
        assert (fr["step"], fr["time"], fr["dt"]) == (expected["step"], expected["time"], expected["dt"])
        # checksums: header bytes 0..59 + table; data region from the table's end
        assert fr["head_crc"] == zlib.crc32(raw[off + 64:off + 64 + fr["table_len"]],
                                            zlib.crc32(raw[off:off + 60]))
        assert fr["data_crc"] == zlib.crc32(raw[off + 64 + fr["table_len"]:end])
        # table contents and array bytes at their offsets
        table = fr["table"]
        assert table["groups"] == {"fluid": 10, "ghost": 3}
        assert table["diagnostics"] == expected["diagnostics"]
        for spec in table["fields"]:
            arr = expected["fields"][spec["name"]]
            assert spec["offset"] % 64 == 0 and spec["dtype"] == arr.dtype.str
            assert spec["shape"] == list(arr.shape)
            pos = fr["data_start"] + spec["offset"]
            assert raw[pos:pos + arr.nbytes] == arr.tobytes()
            assert pos + arr.nbytes <= end
        spec = table["rigid"]["die"]["position"]
        pos = fr["data_start"] + spec["offset"]
        assert spec["dtype"] == "<f8" and raw[pos:pos + 24] == expected["rigid"]["die"]["position"].tobytes()
    # a checkpoint frame differs only in its kind
    assert parse_layout(tmp_path / "cp.cps")["frames"][0]["kind"] == 1


# ---- truncation ----------------------------------------------------------------------

def test_cut_inside_last_frame_at_every_byte_keeps_whole_frames_and_warns(tmp_path):
    path = tmp_path / "run.cps"
    frames = write_run(path, n_frames=3)
    lay = parse_layout(path)
    raw = lay["raw"]
    # every cut strictly inside the last frame
    last = lay["frames"][-1]["offset"]
    for cut in range(last + 1, len(raw)):
        path.write_bytes(raw[:cut])
        with pytest.warns(TruncatedRunWarning, match=r"read 2 whole frames") as record:
            run = corpuscle.open(path)
        assert len(record) == 1 and str(path) in str(record[0].message)
        # the whole frames are intact
        with run:
            assert len(run) == 2
            assert list(run.steps) == [0, 10]
            run.verify()
            assert_frame_equals(run[1], frames[1])


def test_cut_at_any_offset_after_the_header_reads_the_frames_before_it(tmp_path):
    path = tmp_path / "run.cps"
    frames = write_run(path, n_frames=4)
    lay = parse_layout(path)
    raw = lay["raw"]
    # cuts every 7 bytes plus exactly at frame ends (which must not warn)
    ends = [f["offset"] + f["frame_len"] for f in lay["frames"]]
    for cut in list(range(lay["first"], len(raw) + 1, 7)) + ends:
        whole = sum(end <= cut for end in ends)
        path.write_bytes(raw[:cut])
        if cut in ends or cut == lay["first"]:
            run = open_quietly(path)
        else:
            with pytest.warns(TruncatedRunWarning, match=f"read {whole} whole frames"):
                run = corpuscle.open(path)
        with run:
            assert len(run) == whole
            for k in range(whole):
                assert_frame_equals(run[k], frames[k])


def test_cut_inside_the_file_header_raises(tmp_path):
    path = tmp_path / "run.cps"
    write_run(path, n_frames=1)
    # every cut before the first frame, including the empty file
    lay = parse_layout(path)
    for cut in range(0, lay["first"]):
        path.write_bytes(lay["raw"][:cut])
        with pytest.raises(FrameStreamError, match=r"truncated|empty") as err:
            corpuscle.open(path)
        assert str(path) in str(err.value)
    # cut right after the header: a run with no frames yet, no warning
    path.write_bytes(lay["raw"][:lay["first"]])
    with open_quietly(path) as run:
        assert len(run) == 0 and run.header == HEADER and run.series("kinetic_energy").size == 0


def test_reader_sees_each_frame_as_soon_as_it_is_written(tmp_path):
    path = tmp_path / "run.cps"
    # open while writing: the header, then each frame, are already whole on disk
    with FrameWriter(path, HEADER) as w:
        with open_quietly(path) as run:
            assert len(run) == 0
        for k in range(3):
            w.write_frame(**frame_data(k))
            with open_quietly(path) as run:
                assert len(run) == k + 1 and run[-1].step == 10 * k


def test_failed_write_is_cut_back_so_the_file_keeps_whole_frames(tmp_path):
    path = tmp_path / "run.cps"
    w = FrameWriter(path, HEADER)
    w.write_frame(**frame_data(0))
    real_write = w._file.write

    # a disk that fills up halfway through the next frame
    def half_then_fail(data):
        real_write(bytes(data)[: len(data) // 2])
        raise OSError(28, "No space left on device")

    # the failing frame raises and is not counted
    w._file.write = half_then_fail
    with pytest.raises(OSError):
        w.write_frame(**frame_data(1))
    w._file.write = real_write
    # no torn tail is left behind, and the writer carries on after it
    with open_quietly(path) as run:
        assert len(run) == 1
    w.write_frame(**frame_data(2))
    w.close()
    # frames 0 and 2 follow each other as indices 0 and 1
    with open_quietly(path) as run:
        assert len(run) == 2 and list(run.steps) == [0, 20]
        run.verify()


# ---- corruption ----------------------------------------------------------------------

def test_flipped_payload_byte_in_frame_k_names_frame_k_and_spares_the_others(tmp_path):
    path = tmp_path / "run.cps"
    frames = write_run(path, n_frames=4)
    lay = parse_layout(path)
    # every data byte of the first, a middle and the last frame
    for k in (0, 2, 3):
        fr = lay["frames"][k]
        for pos in range(fr["data_start"], fr["offset"] + fr["frame_len"]):
            path.write_bytes(flipped(lay["raw"], pos))
            with open_quietly(path) as run:
                assert len(run) == 4
                with pytest.raises(FrameStreamError,
                                   match=rf"frame {k} is corrupted \(checksum mismatch\)") as err:
                    run[k]
                assert err.value.frame == k and str(path) in str(err.value)
                # the other frames still read, but verify() finds frame k
                for j in set(range(4)) - {k}:
                    assert_frame_equals(run[j], frames[j])
                with pytest.raises(FrameStreamError, match=f"frame {k} "):
                    run.verify()


def test_flipped_byte_in_frame_header_or_table_names_that_frame_and_later_frames_still_read(tmp_path):
    path = tmp_path / "run.cps"
    frames = write_run(path, n_frames=4)
    lay = parse_layout(path)
    # every byte of frame 1's header, table and table padding
    k = 1
    fr = lay["frames"][k]
    for pos in range(fr["offset"], fr["data_start"]):
        path.write_bytes(flipped(lay["raw"], pos))
        with open_quietly(path) as run:
            assert len(run) == 4
            with pytest.raises(FrameStreamError, match=f"frame {k} is corrupted") as err:
                run[k]
            assert err.value.frame == k
            for j in (0, 2, 3):
                assert_frame_equals(run[j], frames[j])
            # a frame whose header is unreadable has no step or time, but the others do
            if pos < fr["offset"] + 64 + fr["table_len"]:
                assert run.steps[k] == -1 and math.isnan(run.times[k])
                assert run.kinds == ["frame", None, "frame", "frame"]
                assert math.isnan(run.series("kinetic_energy")[k])
            assert list(run.steps[[0, 2, 3]]) == [0, 20, 30]
            with pytest.raises(FrameStreamError, match=f"frame {k} "):
                run.verify()


def test_flipped_byte_in_the_last_frames_header_is_an_error_not_a_truncation(tmp_path):
    path = tmp_path / "run.cps"
    write_run(path, n_frames=2)
    lay = parse_layout(path)
    fr = lay["frames"][1]
    # every header byte except frame_len, whose damage cannot be told from a torn write
    for pos in [p for p in range(fr["offset"], fr["offset"] + 64) if not 8 <= p - fr["offset"] < 16]:
        # still two frames: the last is corrupted, not cut off
        path.write_bytes(flipped(lay["raw"], pos))
        with open_quietly(path) as run:
            assert len(run) == 2
            run[0]
            with pytest.raises(FrameStreamError, match="frame 1 is corrupted"):
                run[1]


def test_flipped_byte_in_the_file_header_raises_on_open(tmp_path):
    path = tmp_path / "run.cps"
    write_run(path, n_frames=1)
    lay = parse_layout(path)
    # every byte, padding included, is checked; the message is one line naming the file
    for pos in range(lay["first"]):
        path.write_bytes(flipped(lay["raw"], pos))
        with pytest.raises(FrameStreamError) as err:
            corpuscle.open(path)
        assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_bad_magic_and_empty_file_raise_a_clear_error(tmp_path):
    # a text file, then an empty one
    text = tmp_path / "notes.cps"
    text.write_text("these are not the frames you are looking for\n" * 10)
    with pytest.raises(FrameStreamError, match=r"notes\.cps: not a corpuscle frame stream \(bad magic"):
        corpuscle.open(text)
    empty = tmp_path / "empty.cps"
    empty.write_bytes(b"")
    with pytest.raises(FrameStreamError, match=r"empty\.cps: empty file"):
        corpuscle.open(empty)
    assert issubclass(FrameStreamError, ValueError)


def test_newer_format_version_raises_naming_the_version(tmp_path):
    path = tmp_path / "run.cps"
    write_run(path, n_frames=1)
    # a file from a future writer: version 2
    raw = bytearray(path.read_bytes())
    struct.pack_into("<I", raw, 8, 2)
    path.write_bytes(bytes(raw))
    with pytest.raises(FrameStreamError, match=r"format version 2 is newer than this reader supports \(1\)"):
        corpuscle.open(path)


# ---- access --------------------------------------------------------------------------

def test_indexing_negative_indices_slices_and_iteration(tmp_path):
    path = tmp_path / "run.cps"
    write_run(path, n_frames=5)
    # indices, slices, iteration and the per-frame arrays
    with corpuscle.open(path) as run:
        assert run[-1].index == 4 and run[-5].index == 0 and run[np.int64(2)].step == 20
        assert [f.index for f in run[1:4]] == [1, 2, 3]
        assert [f.index for f in run[::-2]] == [4, 2, 0]
        assert run[7:] == []
        assert [f.step for f in run] == [0, 10, 20, 30, 40]
        np.testing.assert_array_equal(run.steps, [0, 10, 20, 30, 40])
        np.testing.assert_array_equal(run.times, [0.0, 0.01, 0.02, 0.03, 0.04])
        assert run.steps.dtype == np.int64 and not run.steps.flags.writeable
        # out of range, wrong type, missing field
        for bad in (5, -6):
            with pytest.raises(IndexError):
                run[bad]
        with pytest.raises(TypeError):
            run["position"]
        with pytest.raises(KeyError, match="no field 'velocity'"):
            run[0]["velocity"]
        assert "position" in run[0] and "velocity" not in run[0]


def test_series_gives_one_value_per_frame_with_nan_where_missing(tmp_path):
    path = tmp_path / "run.cps"
    with FrameWriter(path, HEADER) as w:
        # diagnostics that come and go across frames
        w.write_frame(0, 0.0, 0.5, {}, diagnostics={"kinetic_energy": 1.0})
        w.write_frame(3, 1.5, 0.25, {}, diagnostics={"kinetic_energy": 2.0, "die_height": 0.1})
        w.write_frame(9, 2.0, 0.125, {}, diagnostics={"die_height": 0.2})
    # NaN where missing; header values by name; unknown names raise
    with corpuscle.open(path) as run:
        np.testing.assert_array_equal(run.series("kinetic_energy"), [1.0, 2.0, np.nan])
        np.testing.assert_array_equal(run.series("die_height"), [np.nan, 0.1, 0.2])
        np.testing.assert_array_equal(run.series("time"), [0.0, 1.5, 2.0])
        np.testing.assert_array_equal(run.series("dt"), [0.5, 0.25, 0.125])
        np.testing.assert_array_equal(run.series("step"), [0, 3, 9])
        assert run.series("kinetic_energy").dtype == np.float64
        assert run.diagnostic_names == ["kinetic_energy", "die_height"]
        with pytest.raises(KeyError, match="density_error"):
            run.series("density_error")


def test_field_names_are_the_union_over_frames_in_first_seen_order(tmp_path):
    path = tmp_path / "run.cps"
    with FrameWriter(path, HEADER) as w:
        # density only in frame 0, velocity only in frame 1
        w.write_frame(0, 0.0, 0.1, {"position": np.zeros((2, 3)), "density": np.zeros(2)})
        w.write_frame(1, 0.1, 0.1, {"position": np.zeros((2, 3)), "velocity": np.zeros((2, 3))})
    with corpuscle.open(path) as run:
        assert run.field_names == ["position", "density", "velocity"]


def test_opening_does_not_read_payloads(tmp_path):
    path = tmp_path / "run.cps"
    write_run(path, n_frames=3)
    lay = parse_layout(path)
    # damage frame 1's data
    fr = lay["frames"][1]
    path.write_bytes(flipped(lay["raw"], fr["data_start"]))
    # a corrupted payload is found only when its frame is read
    with open_quietly(path) as run:
        assert len(run) == 3 and list(run.steps) == [0, 10, 20]
        assert run.series("kinetic_energy")[1] == 0.5
        with pytest.raises(FrameStreamError, match="frame 1 "):
            run[1]


def test_corpuscle_open_is_the_io_reader(tmp_path):
    path = tmp_path / "run.cps"
    write_run(path, n_frames=1)
    # the package-level open is the io reader
    with corpuscle.open(path) as run:
        assert isinstance(run, Run)
    assert corpuscle.__version__ == "0.1.0"


# ---- writer input checks ---------------------------------------------------------------

def test_writer_rejects_inconsistent_or_unsupported_input_with_named_messages(tmp_path):
    path = tmp_path / "run.cps"
    pos = np.zeros((4, 3), np.float32)
    # each bad input names what is wrong
    with FrameWriter(path, HEADER) as w:
        with pytest.raises(ValueError, match=r"field 'density' has 3 rows but group 'fluid' has 4"):
            w.write_frame(0, 0.0, 0.1, {"position": pos, "density": np.zeros(3)})
        with pytest.raises(ValueError, match="ghost_density"):
            w.write_frame(0, 0.0, 0.1, {"position": pos}, groups={"ghost_density": "ghost"})
        with pytest.raises(ValueError, match="kind"):
            w.write_frame(0, 0.0, 0.1, {"position": pos}, kind="snapshot")
        with pytest.raises(TypeError, match="'names' has unsupported dtype"):
            w.write_frame(0, 0.0, 0.1, {"names": np.array(["a", "b"], dtype=object)})
        with pytest.raises(ValueError, match="'energy' must be an array"):
            w.write_frame(0, 0.0, 0.1, {"energy": np.float32(1.0)})
        with pytest.raises(ValueError, match="'die'"):
            w.write_frame(0, 0.0, 0.1, {}, rigid={"die": {"position": [0, 0, 0]}})
        with pytest.raises(ValueError, match="position must have shape"):
            w.write_frame(0, 0.0, 0.1, {}, rigid={"die": {"position": [0, 0, 0, 0],
                                                          "orientation": [1, 0, 0, 0]}})
        with pytest.raises(ValueError, match="orientation must have shape"):
            w.write_frame(0, 0.0, 0.1, {}, rigid={"die": {"position": [0, 0, 0],
                                                          "orientation": [1, 0, 0]}})
        with pytest.raises(ValueError, match="'dt' is reserved"):
            w.write_frame(0, 0.0, 0.1, {}, diagnostics={"dt": 0.1})
        with pytest.raises(TypeError, match="'note' must be a float"):
            w.write_frame(0, 0.0, 0.1, {}, diagnostics={"note": "hello"})
        with pytest.raises(TypeError):
            w.write_frame(0.5, 0.0, 0.1, {})
        # rejected frames leave nothing behind
        assert w.frames_written == 0
    # the file holds no frame, and a closed writer refuses more
    with open_quietly(path) as run:
        assert len(run) == 0
    with pytest.raises(ValueError, match="closed"):
        w.write_frame(0, 0.0, 0.1, {})


def test_writer_rejects_a_header_that_is_not_json_and_creates_no_file(tmp_path):
    path = tmp_path / "run.cps"
    # a function, a NaN (not strict JSON), a list
    with pytest.raises(TypeError, match="not JSON-serialisable"):
        FrameWriter(path, {"callback": print})
    with pytest.raises(ValueError, match="not JSON-serialisable"):
        FrameWriter(path, {"h": math.nan})
    with pytest.raises(TypeError, match="must be a dict"):
        FrameWriter(path, ["scene"])
    assert not path.exists()
