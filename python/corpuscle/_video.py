"""Where rendered frames go: an H.264 .mp4 (imageio-ffmpeg, which ships its own ffmpeg),
an animated .gif, one .png, or a directory of numbered PNGs. Each sink takes frames one at a
time, so a run can be rendered while it records. Outputs appear only when complete: they are
written under hidden temporary names in the same folder and moved into place by ``close()``.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

import numpy as np

from ._viz_common import AtomicOutputs, check_file_output, missing_dirs, prepare_dir, remove_dirs, require

# output kinds by file suffix; anything without a suffix (or an existing folder) is a PNG folder
KINDS = {".mp4": "mp4", ".gif": "gif", ".png": "png"}


def output_kind(out: str | os.PathLike, error: type[ValueError]) -> str:
    """'mp4', 'gif', 'png' or 'dir' for an output path, or ``error`` for an unknown suffix."""
    s = os.fspath(out)
    p = Path(s)
    if p.is_dir() or s.endswith(("/", os.sep)) or not p.suffix:
        return "dir"
    kind = KINDS.get(p.suffix.lower())
    if kind is None:
        raise error(f"cannot render to '{s}': the output must end in .mp4, .gif or .png, or be a directory")
    return kind


class VideoSink:
    """Base sink: ``add(image)`` for each (H, W, 3) uint8 frame, then ``close()``.

    Output is written under temporary names in the output's folder and moved into place by
    ``close()`` once complete; ``abort()`` (or leaving a ``with`` block by an exception)
    removes it instead, so a failed render leaves no partial file behind.
    """

    def __init__(self, path: Path, size: tuple[int, int], fps: float):
        self.path, self.size, self.fps = path, size, fps
        self.frames = 0
        self._outputs = AtomicOutputs()
        self._done = False

    def add(self, image: np.ndarray) -> None:
        """Append one frame."""
        if self._done:
            raise ValueError(f"{self.path}: the output is already closed")
        if image.shape != (self.size[1], self.size[0], 3) or image.dtype != np.uint8:
            raise ValueError(f"frame must be {self.size[1]}x{self.size[0]}x3 uint8, got {image.shape} {image.dtype}")
        self._add(np.ascontiguousarray(image))
        self.frames += 1

    def _add(self, image: np.ndarray) -> None:
        raise NotImplementedError

    def _finish(self) -> None:
        """Complete the temporary output (flush the encoder, write the file)."""

    def _stop(self) -> None:
        """Stop producing output after a failure (the temporaries are removed afterwards)."""

    def close(self) -> None:
        """Finish the output and move it into place. Closing twice is harmless."""
        if self._done:
            return
        self._done = True
        try:
            self._finish()
        except BaseException:
            self._cleanup()
            raise
        self._outputs.commit()

    def abort(self) -> None:
        """Give up: stop the encoder and remove everything written. Harmless after close()."""
        if self._done:
            return
        self._done = True
        self._cleanup()

    def _cleanup(self) -> None:
        with contextlib.suppress(Exception):
            self._stop()
        self._outputs.discard()

    def __enter__(self):
        return self

    def __exit__(self, exc_type, *exc):
        if exc_type is None:
            self.close()
        else:
            self.abort()


class Mp4Sink(VideoSink):
    """H.264 (yuv420p, CRF 18) through imageio-ffmpeg's bundled ffmpeg."""

    def __init__(self, path, size, fps, error):
        super().__init__(path, size, fps)
        self._gen = None
        ffmpeg = require("imageio_ffmpeg", "imageio-ffmpeg", "rendering .mp4", error)
        if size[0] % 2 or size[1] % 2:
            raise error(f"--size for .mp4 must have an even width and height (H.264 4:2:0), got {size[0]}x{size[1]}")
        # the temporary keeps the .mp4 suffix: ffmpeg picks the container by it
        try:
            self._gen = ffmpeg.write_frames(
                os.fspath(self._outputs.path(path)), size, fps=fps, codec="libx264", pix_fmt_in="rgb24",
                pix_fmt_out="yuv420p", quality=None, macro_block_size=1, ffmpeg_log_level="error",
                output_params=["-crf", "18", "-preset", "veryfast", "-movflags", "+faststart"])
            self._gen.send(None)
        except BaseException:
            self._cleanup()
            raise

    def _add(self, image):
        self._gen.send(image)

    def _finish(self):
        gen, self._gen = self._gen, None
        if gen is not None:
            gen.close()

    _stop = _finish


class GifSink(VideoSink):
    """Animated GIF: each frame quantised to its own 255-colour palette, written at close."""

    def __init__(self, path, size, fps, error):
        super().__init__(path, size, fps)
        self._pil = require("PIL.Image", "pillow", "rendering .gif", error)
        self._frames = []

    def _add(self, image):
        im = self._pil.fromarray(image, "RGB")
        self._frames.append(im.quantize(colors=255, method=self._pil.Quantize.FASTOCTREE, dither=self._pil.Dither.NONE))

    def _finish(self):
        frames, self._frames = self._frames, []
        if frames:
            frames[0].save(self._outputs.path(self.path), format="GIF", save_all=True, append_images=frames[1:],
                           duration=max(20, int(round(1000 / self.fps))), loop=0, optimize=False, disposal=1)

    def _stop(self):
        self._frames = []


class PngSink(VideoSink):
    """One PNG: the last frame added."""

    def __init__(self, path, size, fps, error):
        super().__init__(path, size, fps)
        self._pil = require("PIL.Image", "pillow", "rendering .png", error)
        self._last = None

    def _add(self, image):
        self._last = image.copy()

    def _finish(self):
        last, self._last = self._last, None
        if last is not None:
            self._pil.fromarray(last, "RGB").save(self._outputs.path(self.path), format="PNG")

    def _stop(self):
        self._last = None


class PngDirSink(VideoSink):
    """A folder of numbered PNGs, ``frame_00000.png``, ``frame_00001.png``, ...

    Each frame is written under a temporary name; ``close()`` moves them all into place.
    After a failure the frames are removed, and the folder too if this sink created it.
    """

    def __init__(self, path, size, fps, error, created: list | None = None):
        super().__init__(path, size, fps)
        self._pil = require("PIL.Image", "pillow", "rendering PNG frames", error)
        self._created = list(created or [])

    def _add(self, image):
        tmp = self._outputs.path(self.path / f"frame_{self.frames:05d}.png")
        self._pil.fromarray(image, "RGB").save(tmp, format="PNG", compress_level=3)

    def _cleanup(self):
        super()._cleanup()
        remove_dirs(self._created)  # the folders this sink made, if empty again


def open_sink(out: str | os.PathLike, size: tuple[int, int], fps: float, error: type[ValueError]) -> VideoSink:
    """The sink for ``out`` (decided by its suffix), checked writable before any frame is drawn."""
    kind = output_kind(out, error)
    if kind == "dir":
        created = missing_dirs(out)
        folder = prepare_dir(out, error)
        try:
            return PngDirSink(folder, size, fps, error, created=created)
        except BaseException:
            remove_dirs(created)
            raise
    path = check_file_output(out, error)
    return {"mp4": Mp4Sink, "gif": GifSink, "png": PngSink}[kind](path, size, fps, error)
