"""Losslessly compressed, chunked arrays: how rendered camera frames are stored.

Consecutive frames of an episode differ little, so a chunk of ``CHUNK_ROWS`` consecutive rows
compressed together with zstd is ~6-8x smaller than the raw ``uint8`` rows, while one frame
compresses only ~2x on its own (measured on randomized-kitchen frames; see the data card).
A chunk never spans two episodes, so the frames of any episode prefix can be served, and
reading a row decodes only its chunk (~0.15 ms for 8 frames of 128x128x3).

File layout (``<key>.zch``; the sha256 of the whole file is in the shard record, as for
``.npy`` arrays, and every chunk also carries zstd's own content checksum)::

    MAGIC | chunk 0 | chunk 1 | ... | row starts int64 (n+1) | byte offsets int64 (n+1) | header JSON
          | u64 header length | u64 n | MAGIC

A gather (``arr[indices]``) decodes each chunk it touches once, so the frames of a stack and of
the next observation, fetched together by ``Dataset.sample``, cost one decode.  Decoded chunks
are not cached between calls: random batches of a dataset much larger than RAM would rarely hit
such a cache (a 256 MB LRU cache measured no faster, see ``bench/dataset_sampling.py``'s history
in the CHANGELOG), and datasets up to 1 GiB are decoded into RAM when loaded.
"""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path
from typing import BinaryIO

import numpy as np

from d5rl.errors import DatasetCorruptError

MAGIC = b"D5RLZCH1"
ENCODING = "zstd-chunks-1"  # the value of an array record's "encoding"
SUFFIX = ".zch"
# rows per chunk: on randomized-kitchen frames 7.7x smaller than raw at 16 rows, 6.5x at 8, 5.1x at 4;
# a batch decodes every chunk holding one of its rows, so fewer rows per chunk decode less
CHUNK_ROWS = 8
LEVEL = 9  # zstd level: ~110 MB/s to compress (a renderer makes ~3 MB/s), 6.1x vs 5.7x at level 3
_TAIL = struct.Struct("<QQ8s")


def _zstd():
    import zstandard

    return zstandard


class ChunkWriter:
    """Streams rows into a ``.zch`` file: :meth:`append` one episode (or any run of rows that must
    start a new chunk) at a time, then :meth:`close`."""

    def __init__(
        self,
        path: str | os.PathLike,
        row_shape: tuple[int, ...],
        dtype,
        chunk_rows: int = CHUNK_ROWS,
        level: int = LEVEL,
    ):
        self.path = Path(path)
        self.row_shape, self.dtype = tuple(int(x) for x in row_shape), np.dtype(dtype)
        self.chunk_rows = int(chunk_rows)
        self._cctx = _zstd().ZstdCompressor(level=level, write_checksum=True, write_content_size=True)
        self._f: BinaryIO = open(self.path, "wb")
        self._f.write(MAGIC)
        self._rows, self._offsets, self._n = [0], [len(MAGIC)], 0

    def append(self, rows: np.ndarray) -> None:
        rows = np.ascontiguousarray(rows, dtype=self.dtype)
        if rows.shape[1:] != self.row_shape:
            raise ValueError(f"rows of shape {rows.shape[1:]} appended to an array of rows {self.row_shape}")
        for s in range(0, len(rows), self.chunk_rows):
            part = rows[s : s + self.chunk_rows]
            self._f.write(self._cctx.compress(part.tobytes()))
            self._n += len(part)
            self._rows.append(self._n)
            self._offsets.append(self._f.tell())

    def abort(self) -> None:
        self._f.close()

    def close(self) -> tuple[int, ...]:
        """Write the index and close; returns the array's shape."""
        if self._f.closed:
            return (self._n, *self.row_shape)
        header = json.dumps(
            {
                "encoding": ENCODING,
                "rows": self._n,
                "row_shape": self.row_shape,
                "dtype": self.dtype.str,
                "chunk_rows": self.chunk_rows,
            },
            sort_keys=True,
        ).encode()
        self._f.write(np.asarray(self._rows, "<i8").tobytes())
        self._f.write(np.asarray(self._offsets, "<i8").tobytes())
        self._f.write(header)
        self._f.write(_TAIL.pack(len(header), len(self._rows) - 1, MAGIC))
        self._f.close()
        return (self._n, *self.row_shape)


class CompressedArray:
    """A read-only array over a ``.zch`` file (or its first ``rows`` rows): ``len``, ``shape``,
    ``dtype``, integer / slice / integer-array indexing and ``np.asarray``, decoding only the
    chunks that hold the rows asked for."""

    def __init__(self, path: str | os.PathLike, rows: int | None = None):
        self.path = Path(path)
        self._buf = np.memmap(self.path, dtype=np.uint8, mode="r")
        buf = self._buf
        if len(buf) < len(MAGIC) + _TAIL.size or bytes(buf[: len(MAGIC)]) != MAGIC:
            raise ValueError("not a d5rl chunked array (bad magic)")
        hlen, n, magic = _TAIL.unpack(bytes(buf[-_TAIL.size :]))
        end = len(buf) - _TAIL.size
        if magic != MAGIC or end - hlen - 16 * (n + 1) < len(MAGIC):
            raise ValueError("not a d5rl chunked array (bad footer)")
        head = json.loads(bytes(buf[end - hlen : end]))
        if head.get("encoding") != ENCODING:
            raise ValueError(f"unknown chunk encoding {head.get('encoding')!r}")
        idx = np.frombuffer(bytes(buf[end - hlen - 16 * (n + 1) : end - hlen]), "<i8").reshape(2, n + 1)
        self.row_starts, self.offsets = idx[0].copy(), idx[1].copy()
        self.dtype = np.dtype(head["dtype"])
        self.row_shape = tuple(head["row_shape"])
        total = int(head["rows"])
        if self.row_starts[-1] != total or self.offsets[-1] > end - hlen - 16 * (n + 1):
            raise ValueError("inconsistent chunk index")
        self.total_rows = total
        self.shape = (total if rows is None else int(rows), *self.row_shape)
        if not 0 <= self.shape[0] <= total:
            raise ValueError(f"{rows} rows asked of an array of {total}")
        self._dctx = None

    ndim = property(lambda self: len(self.shape))
    nbytes = property(lambda self: int(np.prod(self.shape, dtype=np.int64)) * self.dtype.itemsize)

    def __len__(self) -> int:
        return self.shape[0]

    def head(self, rows: int) -> CompressedArray:
        """The first ``rows`` rows, still compressed (no decoding)."""
        out = CompressedArray.__new__(CompressedArray)
        out.__dict__.update(self.__dict__)
        out.shape = (int(rows), *self.row_shape)
        if not 0 <= rows <= self.total_rows:
            raise ValueError(f"{rows} rows asked of an array of {self.total_rows}")
        return out

    def chunk(self, c: int) -> np.ndarray:
        """Decoded chunk ``c`` (rows ``row_starts[c]:row_starts[c+1]``), read-only."""
        if self._dctx is None:
            self._dctx = _zstd().ZstdDecompressor()
        blob = self._buf[self.offsets[c] : self.offsets[c + 1]]
        n = int(self.row_starts[c + 1] - self.row_starts[c])
        try:
            raw = self._dctx.decompress(blob)
        except _zstd().ZstdError as e:
            raise CorruptChunkError(f"{self.path}: chunk {c} does not decode ({e})") from None
        arr = np.frombuffer(raw, self.dtype)
        if arr.size != n * int(np.prod(self.row_shape)):
            raise CorruptChunkError(f"{self.path}: chunk {c} decodes to {arr.size} values, expected rows {n}")
        return arr.reshape((n, *self.row_shape))

    def __array__(self, dtype=None, copy=None):
        out = np.empty(self.shape, self.dtype)  # every chunk decoded once, in order, straight into place
        n = len(self)
        for c in range(len(self.row_starts) - 1):
            a, b = int(self.row_starts[c]), min(int(self.row_starts[c + 1]), n)
            if a >= n:
                break
            out[a:b] = self.chunk(c)[: b - a]
        return out if dtype is None else out.astype(dtype)

    def __getitem__(self, idx):
        if isinstance(idx, tuple):  # rows first, then the rest on the decoded rows
            rows = self[idx[0]]
            lead = 0 if isinstance(idx[0], (int, np.integer)) else rows.ndim - len(self.row_shape)
            return rows[(slice(None),) * lead + tuple(idx[1:])]
        if isinstance(idx, (int, np.integer)):
            i = int(idx) + (len(self) if idx < 0 else 0)
            if not 0 <= i < len(self):
                raise IndexError(f"index {idx} out of range for length {len(self)}")
            c = int(np.searchsorted(self.row_starts, i, side="right")) - 1
            return self.chunk(c)[i - self.row_starts[c]].copy()
        if isinstance(idx, slice):
            start, stop, step = idx.indices(len(self))
            return self[np.arange(start, stop, step)]
        return gather_rows(idx, len(self), self.row_shape, self.dtype, self.row_starts, self.chunk)


def gather_rows(idx, length: int, row_shape: tuple, dtype, bounds: np.ndarray, chunk) -> np.ndarray:
    """Rows ``idx`` (an integer or boolean index array) of an array stored as consecutive chunks:
    chunk ``c`` holds rows ``bounds[c]:bounds[c + 1]`` and ``chunk(c)`` returns it; each chunk a batch
    needs is read once.  Shared by compressed arrays and the shard-concatenating ``ChunkedArray``."""
    idx = np.asarray(idx)
    if idx.dtype == bool:
        idx = np.flatnonzero(idx)
    flat = idx.reshape(-1).astype(np.int64)
    if flat.size and (flat.min() < 0 or flat.max() >= length):
        raise IndexError(f"index out of range for length {length}")
    out = np.empty((flat.size, *row_shape), dtype)
    if len(bounds) == 2:  # one chunk: gather straight into the output
        np.take(chunk(0), flat, axis=0, out=out)
        return out.reshape(idx.shape + tuple(row_shape))
    which = np.searchsorted(bounds, flat, side="right") - 1
    order = np.argsort(which, kind="stable")
    edges = np.searchsorted(which[order], np.arange(len(bounds)))
    for c in np.flatnonzero(edges[1:] > edges[:-1]):
        sel = order[edges[c] : edges[c + 1]]
        out[sel] = chunk(int(c))[flat[sel] - bounds[c]]
    return out.reshape(idx.shape + tuple(row_shape))


class CorruptChunkError(DatasetCorruptError):
    """A chunk that fails to decode or decodes to the wrong size."""

    def __init__(self, message: str):
        super().__init__(
            message, "run `d5rl verify` then `d5rl generate TASK`: damaged render-cache shards are rendered again"
        )


def compress_array(
    path: str | os.PathLike, array: np.ndarray, segments: list[int] | None = None, chunk_rows: int = CHUNK_ROWS
) -> tuple[int, ...]:
    """Write ``array`` as a ``.zch`` file; chunks restart at each of ``segments`` (row counts,
    e.g. per episode; default: one segment).  Returns the shape."""
    w = ChunkWriter(path, array.shape[1:], array.dtype, chunk_rows)
    try:
        start = 0
        for n in segments if segments is not None else [len(array)]:
            w.append(np.asarray(array[start : start + n]))
            start += n
        if start != len(array):
            raise ValueError(f"segments cover {start} of {len(array)} rows")
    finally:
        shape = w.close()
    return shape
