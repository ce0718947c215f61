"""Tests for the recorded-run frame stream (corpuscle.io, docs/frame_format.md)."""

import json
import math
import mmap
import os
import re
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


# ---- files crafted by the spec (docs/frame_format.md), independently of the writer ----------

MAGIC = b"\x89CPS\r\n\x1a\n"


def align64(n):
    return -(-n // 64) * 64


def file_header_bytes(body: bytes, version=1, json_len=None):
    """A file header for JSON ``body``: header_crc is the CRC of [0, 28) then [32, first)."""
    first = align64(32 + len(body))
    fixed = struct.pack("<8sIIQI", MAGIC, version, 0, len(body) if json_len is None else json_len, 0)
    pad = bytes(first - 32 - len(body))
    crc = zlib.crc32(pad, zlib.crc32(body, zlib.crc32(fixed)))
    return fixed + struct.pack("<I", crc) + body + pad


def frame_bytes(index, table, data=b"", step=0, time=0.0, dt=0.1, kind=0, frame_len=None):
    """A frame: head_crc over [0, 60) then the table, data_crc over [64 + table_len, frame_len)."""
    meta = table if isinstance(table, bytes) else json.dumps(table).encode()
    data_start = align64(64 + len(meta))
    rest = bytes(data_start - 64 - len(meta)) + data + bytes(align64(len(data)) - len(data))
    length = 64 + len(meta) + len(rest) if frame_len is None else frame_len
    head = struct.pack("<8sQQqddIHHI", b"CPSFRAME", length, index, step, time, dt, len(meta), kind, 0,
                       zlib.crc32(rest))
    return head + struct.pack("<I", zlib.crc32(meta, zlib.crc32(head))) + meta + rest


def crafted_run(path, header=b'{"scene":"crafted"}', frames=()):
    path.write_bytes(file_header_bytes(header) + b"".join(frames))
    return path


def base_table():
    """A valid table: field x (4 float32), body die (position, orientation), one diagnostic."""
    return {"groups": {"fluid": 4},
            "fields": [{"name": "x", "group": "fluid", "dtype": "<f4", "shape": [4], "offset": 0}],
            "rigid": {"die": {"position": {"dtype": "<f8", "shape": [3], "offset": 64},
                              "orientation": {"dtype": "<f8", "shape": [4], "offset": 128}}},
            "diagnostics": {"e": 1.5, "m": "-inf"}}


BASE_DATA = (np.arange(4, dtype="<f4").tobytes() + bytes(48) + np.array([1.0, 2.0, 3.0]).tobytes() + bytes(40)
             + np.array([1.0, 0.0, 0.0, 0.0]).tobytes() + bytes(32))


def test_a_frame_crafted_by_the_spec_reads_back(tmp_path):
    path = crafted_run(tmp_path / "c.cps", frames=[frame_bytes(0, base_table(), BASE_DATA, step=7, time=0.5, kind=1)])
    with open_quietly(path) as run:
        run.verify()
        f = run[0]
        assert (f.step, f.time, f.kind, f.counts) == (7, 0.5, "checkpoint", {"fluid": 4})
        np.testing.assert_array_equal(f["x"], [0, 1, 2, 3])
        np.testing.assert_array_equal(f.rigid["die"]["position"], [1, 2, 3])
        assert f.diagnostics == {"e": 1.5, "m": -math.inf}
        assert run.header == {"scene": "crafted"} and run.last_checkpoint().index == 0


def _nested(depth):
    """JSON text of nested arrays ``depth`` deep."""
    return b"[" * depth + b"]" * depth


@pytest.mark.parametrize("body", [_nested(100_000), b'{"a":' * 100_000 + b"1" + b"}" * 100_000,
                                  b'{"a":' + _nested(32) + b"}"],
                         ids=["arrays 100000 deep", "objects 100000 deep", "33 deep"])
def test_deeply_nested_header_json_is_a_one_line_frame_stream_error(tmp_path, body):
    # was a RecursionError from json (and from anything walking the header afterwards)
    path = crafted_run(tmp_path / "deep.cps", header=body)
    with pytest.raises(FrameStreamError, match=r"file header is corrupted \(bad JSON: JSON nested \d+ deep") as err:
        corpuscle.open(path)
    assert "\n" not in str(err.value) and str(path) in str(err.value)
    # so does appending to it
    with pytest.raises(FrameStreamError, match="nested"):
        FrameWriter.append(path)


def test_nesting_up_to_the_limit_is_read_and_brackets_in_strings_do_not_count(tmp_path):
    # {"a": 31 arrays deep} is 32 deep: accepted; strings full of brackets are not nesting
    header = {"a": json.loads(_nested(31)), "s": "[[[{{{" * 1000}
    path = crafted_run(tmp_path / "ok.cps", header=json.dumps(header).encode())
    with open_quietly(path) as run:
        assert run.header == header
    # the writer writes what the reader reads, and refuses one level more
    FrameWriter(tmp_path / "w.cps", header).close()
    with pytest.raises(ValueError, match="nested 33 deep"):
        FrameWriter(tmp_path / "deeper.cps", {"a": json.loads(_nested(32))})
    assert not (tmp_path / "deeper.cps").exists()


def test_header_json_that_is_not_strict_json_or_not_utf8_is_corrupted(tmp_path):
    for body in (b'{"h": NaN}', b'{"h": Infinity}', b'{"h": "\xff"}', b'[1, 2]', b'{"h": ' + b"1" * 5000 + b"}"):
        path = crafted_run(tmp_path / "bad.cps", header=body)
        with pytest.raises(FrameStreamError, match="file header is corrupted") as err:
            corpuscle.open(path)
        assert "\n" not in str(err.value)


def test_json_len_beyond_the_file_is_truncation_not_an_overflow(tmp_path):
    path = tmp_path / "long.cps"
    for json_len in (2**64 - 1, 2**63, 10**9):
        path.write_bytes(file_header_bytes(b"{}", json_len=json_len))
        with pytest.raises(FrameStreamError, match="file header is truncated"):
            corpuscle.open(path)


def _mutate(change):
    """A table made from the base table by ``change`` (which edits it in place)."""
    table = base_table()
    change(table)
    return table


def _field(**kw):
    return lambda t: t["fields"][0].update(kw)


MALFORMED_TABLES = {
    "huge shape": _field(shape=[10**30]),
    "negative shape": _field(shape=[-4]),
    "float shape": _field(shape=[4.0]),
    "bool shape": _field(shape=[True]),
    "string shape": _field(shape="4"),
    "no dimensions": _field(shape=[]),
    "33 dimensions": _field(shape=[4] + [1] * 32),
    "extent over 2**62": _field(shape=[4, 2**61]),
    "<i1 (NumPy writes |i1)": _field(dtype="<i1"),
    "big-endian": _field(dtype=">f4"),
    "long double": _field(dtype="<f16"),
    "object": _field(dtype="O"),
    "dtype name": _field(dtype="float32"),
    "unaligned offset": _field(offset=3),
    "negative offset": _field(offset=-64),
    "string offset": _field(offset="0"),
    "offset outside the frame": _field(offset=64 * 100),
    "count as a string": lambda t: t["groups"].update(fluid="4"),
    "negative count": lambda t: t["groups"].update(fluid=-1),
    "count unlike the rows": lambda t: t["groups"].update(fluid=5),
    "group not listed": _field(group="ghost"),
    "no name": _field(name=""),
    "repeated name": lambda t: t["fields"].append(dict(t["fields"][0])),
    "field not an object": lambda t: t["fields"].append(7),
    "diagnostic string": lambda t: t["diagnostics"].update(e="hello"),
    "diagnostic bool": lambda t: t["diagnostics"].update(e=True),
    "diagnostic object": lambda t: t["diagnostics"].update(e={"v": 1}),
    "diagnostic null": lambda t: t["diagnostics"].update(e=None),
    "rigid float32": lambda t: t["rigid"]["die"]["position"].update(dtype="<f4", shape=[6]),
    "rigid position (4,)": lambda t: t["rigid"]["die"]["position"].update(shape=[4]),
    "rigid orientation (3,)": lambda t: t["rigid"]["die"]["orientation"].update(shape=[3]),
    "rigid no orientation": lambda t: t["rigid"]["die"].pop("orientation"),
    "rigid body not an object": lambda t: t["rigid"].update(die=[1, 2]),
    "no rigid section": lambda t: t.pop("rigid"),
    "fields not a list": lambda t: t.update(fields={}),
    "nested 33 deep": lambda t: t.update(extra=json.loads(_nested(32))),
    "nested 100000 deep": lambda t: t.update(extra=None),  # replaced by raw JSON below
}


@pytest.mark.parametrize("case", list(MALFORMED_TABLES))
def test_a_malformed_table_is_a_one_line_error_naming_the_frame(tmp_path, case):
    table = json.dumps(_mutate(MALFORMED_TABLES[case])).encode()
    if case == "nested 100000 deep":
        table = table.replace(b'"extra": null', b'"extra": ' + _nested(100_000))
    path = crafted_run(tmp_path / "m.cps", frames=[frame_bytes(0, base_table(), BASE_DATA),
                                                   frame_bytes(1, table, BASE_DATA)])
    # opening works; frame 1 raises a one-line FrameStreamError naming it, frame 0 still reads
    with open_quietly(path) as run:
        assert len(run) == 2
        run[0]
        with pytest.raises(FrameStreamError, match="frame 1 is malformed") as err:
            run[1]
        assert err.value.frame == 1 and "\n" not in str(err.value)
        with pytest.raises(FrameStreamError, match="frame 1 is malformed"):
            run.verify()
        # the table readers too: never a TypeError, KeyError or RecursionError (where an
        # array lies is checked against the frame's bytes only when the frame is read)
        if case == "offset outside the frame":
            return
        for read in (lambda: run.field_names, lambda: run.diagnostic_names, lambda: run.series("e")):
            with pytest.raises(FrameStreamError, match="frame 1 is malformed"):
                read()


def test_table_text_that_is_not_a_json_object_is_malformed(tmp_path):
    for raw in (b"[]", b"{", b'{"groups": NaN}', b"\xff\xfe", b"null"):
        path = crafted_run(tmp_path / "t.cps", frames=[frame_bytes(0, raw)])
        with open_quietly(path) as run, pytest.raises(FrameStreamError, match="frame 0 is malformed"):
            run[0]


def test_a_frame_whose_length_runs_far_past_the_end_is_a_torn_tail(tmp_path):
    # a readable header (head_crc matches) claiming 2**64 - 64 bytes: truncation, no overflow
    path = crafted_run(tmp_path / "t.cps", frames=[frame_bytes(0, base_table(), BASE_DATA),
                                                   frame_bytes(1, base_table(), BASE_DATA, frame_len=2**64 - 64)])
    with pytest.warns(TruncatedRunWarning, match="read 1 whole frames"):
        run = corpuscle.open(path)
    with run:
        assert len(run) == 1 and run.torn_bytes == len(frame_bytes(1, base_table(), BASE_DATA))


@pytest.mark.parametrize("tail", [b"\0", b"\0" * 63, b"\0" * 64, b"\0" * 1000, b"CPSFRAME" + bytes(200),
                                  bytes(range(256)) * 3],
                         ids=["1 zero", "63 zeros", "64 zeros", "1000 zeros", "frame magic", "garbage"])
def test_trailing_bytes_after_the_last_frame_are_a_torn_tail_and_append_cuts_them(tmp_path, tail):
    path = tmp_path / "run.cps"
    frames = write_run(path, n_frames=2)
    size = path.stat().st_size
    with open(path, "ab") as f:
        f.write(tail)
    # ignored with the truncation warning; the whole frames are intact
    with pytest.warns(TruncatedRunWarning, match=rf"\({len(tail)} trailing bytes ignored\); read 2 whole frames"):
        run = corpuscle.open(path)
    with run:
        assert len(run) == 2 and run.torn_bytes == len(tail)
        run.verify()
        assert_frame_equals(run[1], frames[1])
    # appending cuts them off and carries on
    with FrameWriter.append(path) as w:
        assert path.stat().st_size == size and w.frames_written == 2
        w.write_frame(**frame_data(2))
    with open_quietly(path) as run:
        assert len(run) == 3 and run.torn_bytes == 0
        assert_frame_equals(run[2], frame_data(2))


def test_zero_length_arrays_share_their_offset_with_the_next_array(tmp_path):
    path = tmp_path / "run.cps"
    with FrameWriter(path, HEADER) as w:
        w.write_frame(0, 0.0, 0.1, {"empty": np.zeros((0, 3), np.float32), "x": np.arange(5.0),
                                    "none": np.zeros(0, np.int8)},
                      groups={"empty": "ghost", "none": "other"})
    lay = parse_layout(path)
    fr = lay["frames"][0]
    offsets = {s["name"]: s["offset"] for s in fr["table"]["fields"]}
    # "empty" takes no bytes: it starts where "x" does; "none", last, at the region's end
    assert offsets["empty"] == offsets["x"] == 0
    assert fr["data_start"] + offsets["none"] == fr["offset"] + fr["frame_len"]
    with open_quietly(path) as run:
        f = run[0]
        assert f["empty"].shape == (0, 3) and f["none"].shape == (0,) and f["none"].dtype == np.int8
        np.testing.assert_array_equal(f["x"], np.arange(5.0))
        assert f.counts == {"ghost": 0, "fluid": 5, "other": 0}


def test_a_zero_length_array_past_the_data_region_is_malformed(tmp_path):
    table = base_table()
    table["groups"]["e"] = 0
    table["fields"].append({"name": "z", "group": "e", "dtype": "<f4", "shape": [0], "offset": 192})
    ok = crafted_run(tmp_path / "ok.cps", frames=[frame_bytes(0, table, BASE_DATA)])
    with open_quietly(ok) as run:
        assert run[0]["z"].shape == (0,)  # offset 192 is the end of the 192-byte region: fine
    table["fields"][-1]["offset"] = 256
    bad = crafted_run(tmp_path / "bad.cps", frames=[frame_bytes(0, table, BASE_DATA)])
    with open_quietly(bad) as run, pytest.raises(FrameStreamError, match="array outside its frame"):
        run[0]


DOC = (__import__("pathlib").Path(__file__).resolve().parents[2] / "docs" / "frame_format.md").read_text()


def test_the_documented_dtypes_are_exactly_what_the_writer_writes_and_the_reader_accepts(tmp_path):
    from corpuscle.io import DTYPES

    # the list in docs/frame_format.md
    block = DOC[DOC.index("`dtype` is one of exactly"):DOC.index("One-byte types are written")]
    documented = re.findall(r"`([|<][a-z]\d+)`", block)
    assert sorted(documented) == sorted(DTYPES) and len(documented) == len(DTYPES) == 14
    # every carried NumPy type, as the writer stores it
    types = [np.bool_, np.int8, np.int16, np.int32, np.int64, np.uint8, np.uint16, np.uint32, np.uint64,
             np.float16, np.float32, np.float64, np.complex64, np.complex128]
    path = tmp_path / "run.cps"
    with FrameWriter(path, {}) as w:
        w.write_frame(0, 0.0, 0.1, {f"a{k}": np.zeros(2, t) for k, t in enumerate(types)})
        w.write_frame(1, 0.0, 0.1, {f"b{k}": np.zeros(2, np.dtype(t).newbyteorder(">")) for k, t in enumerate(types)})
    lay = parse_layout(path)
    for fr in lay["frames"]:
        assert sorted(s["dtype"] for s in fr["table"]["fields"]) == sorted(DTYPES)
    with open_quietly(path) as run:
        run.verify()
    # platform-dependent long doubles and non-numeric arrays are refused
    with FrameWriter(tmp_path / "x.cps", {}) as w:
        for bad in (np.zeros(2, np.longdouble), np.zeros(2, np.clongdouble), np.array(["a"]), np.zeros(2, "M8[s]")):
            if bad.dtype.newbyteorder("<").str in DTYPES:
                continue  # long double is double on this platform
            with pytest.raises(TypeError, match="unsupported dtype"):
                w.write_frame(0, 0.0, 0.1, {"v": bad})
        with pytest.raises(ValueError, match="at most 32 dimensions"):
            w.write_frame(0, 0.0, 0.1, {"v": np.zeros((1,) * 33)})


def test_checksum_coverage_is_as_documented(tmp_path):
    # every byte is covered by exactly one CRC except the CRC fields themselves
    path = tmp_path / "run.cps"
    write_run(path, n_frames=3)
    lay = parse_layout(path)
    cover = np.zeros(len(lay["raw"]), int)
    cover[0:28] += 1
    cover[32:lay["first"]] += 1                                  # header_crc
    for fr in lay["frames"]:
        off, tl = fr["offset"], fr["table_len"]
        cover[off:off + 60] += 1
        cover[off + 64:off + 64 + tl] += 1                       # head_crc
        cover[off + 64 + tl:off + fr["frame_len"]] += 1          # data_crc
    uncovered = set(range(28, 32)) | {fr["offset"] + k for fr in lay["frames"] for k in range(60, 64)}
    assert {int(i) for i in np.flatnonzero(cover == 0)} == uncovered
    assert set(np.unique(cover)) == {0, 1}
    # the doc says so in these words
    assert "Bytes covered by **no** CRC" in DOC and "exactly one CRC" in DOC


def test_documented_reading_api_exists(tmp_path):
    path = tmp_path / "run.cps"
    write_run(path, n_frames=2)
    api = DOC[DOC.index("## Reading API"):DOC.index("## Versioning")]
    run_names = set(re.findall(r"`run\.(\w+)", api))
    frame_names = set(re.findall(r"`frame\.(\w+)", api))
    assert {"header", "steps", "times", "kinds", "series", "field_names", "diagnostic_names", "verify",
            "last_checkpoint", "close"} <= run_names
    assert {"fields", "rigid", "counts", "groups", "diagnostics", "kind", "index", "step", "time", "dt"} <= frame_names
    with open_quietly(path) as run:
        frame = run[0]
        for name in run_names:
            assert hasattr(run, name), name
        for name in frame_names:
            assert hasattr(frame, name), name
        assert run.kinds == ["frame", "frame"] and all(isinstance(k, str) for k in run.kinds)
        assert len(run) == 2 and [f.index for f in run] == [0, 1] and run[-1].index == 1


def test_special_files_are_refused_without_blocking(tmp_path):
    import subprocess
    import sys

    fifo = tmp_path / "pipe.cps"
    os.mkfifo(fifo)
    # in a child process, so a regression (blocking open) fails on the timeout, not by hanging
    code = ("import corpuscle, sys\ntry:\n    corpuscle.open(sys.argv[1])\nexcept Exception as e:\n"
            "    print(type(e).__name__, e)")
    out = subprocess.run([sys.executable, "-c", code, str(fifo)], capture_output=True, text=True, timeout=60)
    assert out.stdout.startswith("FrameStreamError") and "not a regular file" in out.stdout
    with pytest.raises(FrameStreamError, match="is a directory"):
        corpuscle.open(tmp_path)


# ---- appending (resume) --------------------------------------------------------------------

def test_append_to_a_complete_file_continues_the_indices(tmp_path):
    path = tmp_path / "run.cps"
    frames = write_run(path, n_frames=3)
    head = parse_layout(path)
    with FrameWriter.append(path) as w:
        assert w.frames_written == 3 and w.header == HEADER
        for k in (3, 4):
            w.write_frame(**frame_data(k))
        assert w.frames_written == 5
    lay = parse_layout(path)
    # the file header is unchanged byte for byte; indices run on; every frame intact
    assert lay["raw"][:head["first"]] == head["raw"][:head["first"]]
    assert [f["index"] for f in lay["frames"]] == [0, 1, 2, 3, 4] and lay["end"] == len(lay["raw"])
    with open_quietly(path) as run:
        run.verify()
        for k, expected in enumerate(frames + [frame_data(3), frame_data(4)]):
            assert_frame_equals(run[k], expected)


def test_append_to_a_file_with_a_torn_tail_cuts_it_back(tmp_path):
    path = tmp_path / "run.cps"
    frames = write_run(path, n_frames=3)
    raw = path.read_bytes()
    lay = parse_layout(path)
    last = lay["frames"][-1]["offset"]
    for cut in sorted({last + 1, last + 63, last + 64, last + 200, len(raw) - 1}):
        path.write_bytes(raw[:cut])
        with FrameWriter.append(path) as w:
            assert w.frames_written == 2 and path.stat().st_size == last
            w.write_frame(**frame_data(7))
        with open_quietly(path) as run:
            assert len(run) == 3 and [f.index for f in run] == [0, 1, 2]
            run.verify()
            assert_frame_equals(run[1], frames[1])
            assert_frame_equals(run[2], frame_data(7))
    # a file holding only its header gets frame 0
    path.write_bytes(raw[:lay["first"] + 10])
    with FrameWriter.append(path) as w:
        assert w.frames_written == 0
        w.write_frame(**frame_data(0))
    with open_quietly(path) as run:
        assert len(run) == 1 and parse_layout(path)["frames"][0]["index"] == 0


def test_append_refuses_what_is_not_a_stream(tmp_path):
    text = tmp_path / "notes.cps"
    text.write_text("not a run\n" * 20)
    empty = tmp_path / "empty.cps"
    empty.write_bytes(b"")
    cut = tmp_path / "cut.cps"
    write_run(cut, n_frames=1)
    cut.write_bytes(cut.read_bytes()[:40])
    for path, words in ((text, "not a corpuscle frame stream"), (empty, "empty file"),
                        (cut, "file header is truncated"), (tmp_path, "is a directory")):
        before = path.read_bytes() if path.is_file() else None
        with pytest.raises(FrameStreamError, match=words) as err:
            FrameWriter.append(path)
        assert "\n" not in str(err.value)
        if before is not None:
            assert path.read_bytes() == before
    with pytest.raises(FileNotFoundError):
        FrameWriter.append(tmp_path / "missing.cps")


def test_append_refuses_a_file_corrupted_before_its_end_and_leaves_it_alone(tmp_path):
    path = tmp_path / "run.cps"
    write_run(path, n_frames=3)
    lay = parse_layout(path)
    # a damaged payload in the middle, a damaged header in the middle, a damaged whole last frame
    for k, pos in ((1, lay["frames"][1]["data_start"] + 5), (1, lay["frames"][1]["offset"] + 20),
                   (2, lay["frames"][2]["data_start"])):
        bad = flipped(lay["raw"], pos)
        path.write_bytes(bad)
        with pytest.raises(FrameStreamError, match=f"frame {k} is corrupted") as err:
            FrameWriter.append(path)
        assert err.value.frame == k and "\n" not in str(err.value)
        assert path.read_bytes() == bad


def test_append_keep_cuts_back_to_a_checkpoint_and_last_checkpoint_finds_it(tmp_path):
    path = tmp_path / "run.cps"
    with FrameWriter(path, HEADER) as w:
        w.write_frame(**frame_data(0))
        w.write_frame(**frame_data(1), kind="checkpoint")
        w.write_frame(**frame_data(2))
        w.write_frame(**frame_data(3), kind="checkpoint")
        w.write_frame(**frame_data(4))
    with open_quietly(path) as run:
        cp = run.last_checkpoint()
        assert cp.index == 3 and cp.kind == "checkpoint" and cp.step == 30
    with FrameWriter.append(path, keep=2) as w:
        assert w.frames_written == 2
        w.write_frame(**frame_data(9))
    with open_quietly(path) as run:
        assert run.kinds == ["frame", "checkpoint", "frame"] and list(run.steps) == [0, 10, 90]
        assert run.last_checkpoint().index == 1
        run.verify()
    with pytest.raises(ValueError, match="keep must be in 0..3"):
        FrameWriter.append(path, keep=4)


def test_last_checkpoint_is_none_without_checkpoints(tmp_path):
    path = tmp_path / "run.cps"
    write_run(path, n_frames=2)
    with open_quietly(path) as run:
        assert run.last_checkpoint() is None
    FrameWriter(path, HEADER).close()
    with open_quietly(path) as run:
        assert run.last_checkpoint() is None


def test_a_file_full_of_frame_magics_is_scanned_in_bounded_time(tmp_path, monkeypatch):
    import corpuscle._frame_reader as cio  # the reader's checksums

    # frame 0, then a damaged frame 1, then a frame magic at every 64-byte slot, each claiming
    # index 1 and a table running to the end of the file (and failing its checksum)
    first = frame_bytes(0, base_table(), BASE_DATA)
    body = bytearray(64 * 20_000)
    for k in range(0, len(body), 64):
        struct.pack_into("<8sQQqddIHHII", body, k, b"CPSFRAME", 128, 1, 0, 0.0, 0.0, len(body) - k - 64, 0, 0, 0, 1)
    path = crafted_run(tmp_path / "magic.cps", frames=[first, bytes(body)])
    size = path.stat().st_size
    # count the bytes checksummed: linear in the file's size, not quadratic (that was ~10 GB)
    seen = []

    class CountingZlib:
        @staticmethod
        def crc32(data, value=0):
            seen.append(len(data))
            return zlib.crc32(data, value)

    monkeypatch.setattr(cio, "zlib", CountingZlib)
    with pytest.warns(TruncatedRunWarning, match="read 1 whole frames"):
        run = corpuscle.open(path)
    assert sum(seen) <= 3 * size
    with run:
        assert len(run) == 1 and run.torn_bytes == len(body)
