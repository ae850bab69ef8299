# SPDX-License-Identifier: GPL-3.0-or-later
"""PC2 point caches: the file Blender's Mesh Cache modifier plays back.

Layout (little-endian): a 32-byte header ``"POINTCACHE2\\0"``, int32 version 1,
int32 vertex count, float32 start, float32 sampling, int32 frame count; then
frame after frame of float32 xyz. Files are only ever replaced whole: written
to a temporary file beside the target and renamed over it, so a reader (the
modifier, another computer on the farm) never sees half a cache.
"""

from __future__ import annotations

import os
import pathlib
import struct
import tempfile
import threading

import numpy as np

HEADER = struct.Struct("<12siiffi")
MAGIC = b"POINTCACHE2\0"

# Frames from this size on (1.4M vertices) are written by a thread of their own. Below it the
# write is a fraction of a millisecond, less than what handing it over costs: the thread needs
# Python's lock back when the write returns, and the bake's thread can wait for it for
# milliseconds (a 100k-vertex bake frame took 2.4 ms longer with every frame handed over).
BACKGROUND_BYTES = 16 * 2**20


class CacheError(ValueError):
    """A cache that cannot be read or written; the message names the file."""


def read(path: str | os.PathLike) -> tuple[np.ndarray, float, float]:
    """Returns ``(frames (F, N, 3) float32, start, sampling)``."""
    path = pathlib.Path(path)
    try:
        data = path.read_bytes()
    except OSError as error:
        raise CacheError(f"cannot read the cache {path}: {error.strerror or error}") from None
    if len(data) < HEADER.size:
        raise CacheError(f"{path} is not a PC2 cache: {len(data)} bytes, shorter than the header")
    magic, version, vertex_count, start, sampling, frame_count = HEADER.unpack_from(data)
    if magic != MAGIC or version != 1:
        raise CacheError(f"{path} is not a PC2 cache (header {magic!r}, version {version})")
    expected = HEADER.size + 12 * vertex_count * frame_count
    if len(data) != expected:
        raise CacheError(f"{path} is truncated: {len(data)} bytes, the header promises {expected}")
    frames = np.frombuffer(data, dtype="<f4", offset=HEADER.size).reshape(frame_count, vertex_count, 3)
    return frames.astype(np.float32), start, sampling


def frame_count(path: str | os.PathLike) -> int:
    """Frames in the cache at ``path``; 0 where there is no readable cache."""
    try:
        with open(path, "rb") as file:
            header = file.read(HEADER.size)
    except OSError:
        return 0
    if len(header) < HEADER.size:
        return 0
    magic, version, _, _, _, frames = HEADER.unpack(header)
    return frames if magic == MAGIC and version == 1 else 0


class Writer:
    """Streams frames into a temporary file; :meth:`commit` renames it over the cache.

    Until ``commit``, the existing cache is untouched; :meth:`abort` (or an
    exception inside a ``with`` block) removes the temporary file.

    A frame of millions of vertices (``BACKGROUND_BYTES`` and more) is
    written by a thread of its own while the caller goes on to the next one:
    it is tens of megabytes, and once the kernel's dirty pages fill up,
    writing it waits on the disk (125 ms per 5M-vertex frame on the
    benchmark host) where it could overlap the next frame's solve. One write
    is in flight at a time; an error it meets is raised by the next
    :meth:`append` or by :meth:`commit`.
    """

    def __init__(
        self, path: str | os.PathLike, vertex_count: int, start: float, sampling: float = 1.0, expected_frames: int = 0
    ):
        self.path = pathlib.Path(path)
        self.vertex_count = vertex_count
        self.start = float(start)
        self.sampling = float(sampling)
        self.frames = 0
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            handle, temporary = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tmp", dir=self.path.parent)
        except OSError as error:
            # "File exists" from mkdir means a file sits where a folder should be: say which.
            parents = [self.path.parent, *self.path.parent.parents]
            blocker = next((p for p in parents if p.exists() and not p.is_dir()), None)
            reason = f"{blocker} is a file, not a folder" if blocker else error.strerror or error
            raise CacheError(f"cannot write the cache in {self.path.parent}: {reason}") from None
        self.temporary = pathlib.Path(temporary)
        if expected_frames > 0:
            # Reserving the whole file up front spares ext4 allocating blocks
            # frame by frame (a 100k-vertex frame: 0.33 -> 0.27 ms to write).
            # A hint only: commit() cuts the file to the frames written, and a
            # file system without fallocate just grows it.
            try:
                os.posix_fallocate(handle, 0, HEADER.size + 12 * vertex_count * expected_frames)
            except (OSError, AttributeError):
                pass
        self.file = os.fdopen(handle, "wb")
        self._staging: np.ndarray | None = None  # the frame being written, a copy the caller cannot touch
        self._writing: threading.Thread | None = None
        self._write_error: OSError | None = None
        self._guard(self.file.write, self._header())

    def _header(self) -> bytes:
        return HEADER.pack(MAGIC, 1, self.vertex_count, self.start, self.sampling, self.frames)

    def _guard(self, action, *args):
        try:
            return action(*args)
        except OSError as error:
            self._fail(error)

    def _fail(self, error: OSError):
        self.abort()
        raise CacheError(f"cannot write the cache {self.path}: {error.strerror or error}") from None

    def _write_staged(self) -> None:
        try:
            self.file.write(memoryview(self._staging).cast("B"))  # releases the GIL while the disk works
        except OSError as error:
            self._write_error = error

    def _wait_for_write(self) -> None:
        """Waits for the frame in flight; raises (having aborted) what its write met."""
        if self._writing is not None:
            self._writing.join()
            self._writing = None
        if self._write_error is not None:
            error, self._write_error = self._write_error, None
            self._fail(error)

    def append(self, positions: np.ndarray) -> None:
        """Adds one frame, ``(N, 3)``; refuses a wrong size or anything not finite."""
        positions = np.ascontiguousarray(positions, dtype="<f4")
        if positions.shape != (self.vertex_count, 3):
            self.abort()
            raise CacheError(f"cache frame {self.frames} has shape {positions.shape}, expected ({self.vertex_count}, 3)")
        if not np.isfinite(positions).all():  # one pass; the search for the culprit only on failure
            bad = np.argwhere(~np.isfinite(positions))
            self.abort()
            raise CacheError(f"refusing to write {self.path}: vertex {bad[0][0]} of cache frame {self.frames} is not finite")
        self._wait_for_write()
        if positions.nbytes < BACKGROUND_BYTES:
            self._guard(self.file.write, memoryview(positions).cast("B"))  # no copy of the frame
            self.frames += 1
            return
        if self._staging is None:
            self._staging = np.empty_like(positions)
        np.copyto(self._staging, positions)
        self._writing = threading.Thread(target=self._write_staged, name=f"tegument-pc2-{self.path.name}", daemon=True)
        self._writing.start()
        self.frames += 1

    def commit(self) -> None:
        """Finishes the header and atomically replaces the cache."""
        self._wait_for_write()

        def finish():
            self.file.seek(0)
            self.file.write(self._header())
            self.file.flush()
            self.file.truncate(HEADER.size + 12 * self.vertex_count * self.frames)  # the reserve not used
            os.fsync(self.file.fileno())
            self.file.close()
            os.replace(self.temporary, self.path)

        self._guard(finish)

    def abort(self) -> None:
        if self._writing is not None and self._writing is not threading.current_thread():
            self._writing.join()  # its error, if any, is moot: the file goes
            self._writing = None
        if not self.file.closed:
            self.file.close()
        self.temporary.unlink(missing_ok=True)

    def __enter__(self):
        return self

    def __exit__(self, kind, value, traceback):
        if kind is not None:
            self.abort()


def write(path: str | os.PathLike, frames: np.ndarray, start: float, sampling: float = 1.0) -> None:
    """Replaces ``path`` atomically with ``frames`` (F, N, 3), refusing anything not finite."""
    frames = np.asarray(frames)
    if frames.ndim != 3 or frames.shape[2] != 3:
        raise CacheError(f"cache frames must have shape (frames, vertices, 3), got {frames.shape}")
    with Writer(path, frames.shape[1], start, sampling, expected_frames=len(frames)) as writer:
        for frame in frames:
            writer.append(frame)
        writer.commit()
