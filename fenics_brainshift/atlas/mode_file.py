"""An atlas's modes as an update reads them: from atlas.h5 a piece at a time, each piece
checked as it is read.

At clinical resolution an atlas holds hundreds of modes over a hundred thousand nodes (417 MB
at 3 mm, 1.7 GB with a patient's fine surface: benchmarks/results/patient_resolution.md), and
an update uses little of it: every mode at the nodes around its points (its rows), every mode
at the boundary (the skull's rows and the surface: stored apart, contiguous, read whole) and,
over the whole mesh, the few modes its weights use (the answer and its spread). The mode array
is contiguous and uncompressed (store.py says why), so it is mapped (mmap), not read: the
operating system reads the pages an update touches, and the process holds no other copy. A
service that holds the atlas for an operation reads it all into memory instead (hold()).

Each piece is checked against what the build recorded, before it is used: a whole mode
against its CRC-32 (exact); the modes at a node against a weighted sum of them there
(checks/node_sum: any change above 1e-11 of the node's modes in magnitude, a flipped sign
too). A damaged piece an update reads is named (InputError), never computed with; damage
where no update reads cannot change an answer."""

from __future__ import annotations

import mmap
import zlib

import numpy as np

from ..errors import InputError

NODE_SUM_TOLERANCE = 1e-11  # of the sum of magnitudes: float64 sums of float32 values err below 1e-13


def mode_crc(mode: np.ndarray) -> int:
    """CRC-32 of one mode's float32 bytes (as stored)."""
    return zlib.crc32(np.ascontiguousarray(mode, dtype="<f4"))


def node_weights(count: int) -> np.ndarray:
    """(M, 3) weights of the node sums: fixed and unequal (two values exchanged change a sum, as
    a value's sign changed does: a sum of squares would miss both)."""
    rng = np.random.default_rng(20261207)
    return rng.uniform(1.0, 2.0, (count, 3)) * rng.choice([-1.0, 1.0], (count, 3))


def node_sums(block: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sum, sum of magnitudes) over modes and components of weights * block, per node, for
    modes at nodes (M, n, 3) (float32 as stored)."""
    values = block.astype(np.float64)
    return np.einsum("knd,kd->n", values, weights), np.einsum("knd,kd->n", np.abs(values), np.abs(weights))


def mapped(handle, offset: int, shape: tuple) -> np.ndarray:
    """The float32 array (shape) at offset in an open file, mapped read-only, its pages read at
    random: every mode at a node is a page per mode, and the kernel's read-ahead around each
    would read most of the file to gather a few nodes; StoredModes asks for the pages it will
    read at once instead (MADV_WILLNEED; the cold-disk times: update_command_cold.md)."""
    mapping = mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ)
    if hasattr(mapping, "madvise"):  # (Linux and macOS)
        mapping.madvise(mmap.MADV_RANDOM)
    return np.ndarray(shape, dtype="<f4", buffer=mapping, offset=offset)


class StoredModes:
    """Modes (M, N, 3) float32 read as they are asked for: ``modes[k]``, ``modes[used]`` (whole
    modes) and ``modes[:, nodes, :]`` or ``modes[..., nodes, :]`` (every mode at some nodes),
    each returned as a new array and checked the first time it is read; ``hold()`` reads and
    checks all of it into memory (a service that holds the atlas for an operation).
    ``np.asarray(modes)`` reads and checks every mode."""

    def __init__(self, values, crc: np.ndarray, weights: np.ndarray, sums: np.ndarray, folder: str):
        self._values = values  # numpy.memmap of atlas.h5 (or an array read whole: store.py)
        self._crc, self._weights, self._sums, self._folder = crc, weights, sums, folder
        self._mode_ok = np.zeros(values.shape[0], dtype=bool)
        self._node_ok = np.zeros(values.shape[1], dtype=bool)
        self.shape, self.dtype, self.ndim = values.shape, values.dtype, 3
        self._mapping = values.base if isinstance(values.base, mmap.mmap) and hasattr(values.base, "madvise") else None
        if self._mapping is not None:  # (where the array begins in the file)
            self._start = values.ctypes.data - np.frombuffer(self._mapping, np.uint8, 1).ctypes.data

    def __len__(self) -> int:
        return self.shape[0]

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        """Every mode, read and checked (numpy's view of it: np.asarray, arithmetic with arrays)."""
        return self._modes(slice(None)).astype(dtype or self.dtype, copy=False)

    def astype(self, dtype) -> np.ndarray:
        return np.asarray(self, dtype=dtype)

    def __getitem__(self, key):
        key = key if isinstance(key, tuple) else (key,)
        nodes_form = (len(key) == 3 and key[0] is Ellipsis) or (len(key) in (2, 3) and _whole(key[0]))
        if nodes_form and all(map(_whole, key[2:])):
            if not isinstance(key[1], slice):
                return self._at_nodes(np.asarray(key[1]))
        if len(key) <= 3 and key[0] is not Ellipsis and all(map(_whole, key[1:])):
            return self._modes(key[0])
        raise TypeError(f"StoredModes reads whole modes or every mode at some nodes, not {key!r}")

    def _modes(self, which) -> np.ndarray:
        chosen = np.arange(len(self))[which].ravel()
        self._will_need(chosen[~self._mode_ok[chosen]])
        for k in chosen:
            if not self._mode_ok[k]:
                if mode_crc(self._values[k]) != int(self._crc[k]):
                    self._damaged(f"mode {k} is not what the build wrote (its CRC-32)")
                self._mode_ok[k] = True
        return np.array(self._values[which])

    def _will_need(self, modes: np.ndarray) -> None:
        """Ask the kernel for these whole modes' pages at once (a mapping read at random)."""
        if self._mapping is None:
            return
        size = self._values[0].nbytes
        for k in modes:
            begin = (self._start + int(k) * size) // mmap.PAGESIZE * mmap.PAGESIZE  # (a page's start)
            self._mapping.madvise(mmap.MADV_WILLNEED, begin, self._start + (int(k) + 1) * size - begin)

    def _will_need_nodes(self, nodes: np.ndarray) -> None:
        """Ask the kernel for the pages of every mode at these nodes at once, so that the disk reads
        them in parallel, not a page fault after another (benchmarks/update_command.py --cold);
        only for nodes not read before (from the page cache the calls cost time too)."""
        if self._mapping is None or not len(nodes):
            return
        size = self._values[0].nbytes
        first = self._start + np.arange(len(self))[:, None] * size + nodes[None, :] * 12
        pages = np.unique(np.concatenate([first.ravel(), first.ravel() + 11]) // mmap.PAGESIZE)
        breaks = np.flatnonzero(np.diff(pages) > 1) + 1  # (runs of consecutive pages: one call each)
        for run in np.split(pages, breaks):
            self._mapping.madvise(mmap.MADV_WILLNEED, int(run[0]) * mmap.PAGESIZE, len(run) * mmap.PAGESIZE)

    def _at_nodes(self, nodes: np.ndarray) -> np.ndarray:
        nodes = np.where(nodes < 0, nodes + self.shape[1], nodes)  # (numpy's negative indices, as numbers)
        unique, inverse = np.unique(nodes.ravel(), return_inverse=True)
        self._will_need_nodes(unique[~self._node_ok[unique]])
        block = np.array(self._values[:, unique, :])
        self.check_nodes(unique, block)
        return block[:, inverse.reshape(nodes.shape), :]

    def check_nodes(self, nodes: np.ndarray, block: np.ndarray) -> None:
        """Every mode at these nodes (M, n, 3), as read, checked against the build's node sums."""
        todo = ~self._node_ok[nodes]
        if not todo.any():
            return
        total, size = node_sums(block[:, todo, :], self._weights)
        bad = ~(np.abs(total - self._sums[nodes[todo]]) <= NODE_SUM_TOLERANCE * size)  # (NaN: bad)
        if bad.any():
            self._damaged(f"the modes at node {int(nodes[todo][bad][0])} are not what the build wrote")
        self._node_ok[nodes[todo]] = True

    def hold(self) -> None:
        """Read every mode into memory and check it, the file's mapping dropped: for a service
        that holds the atlas for an operation. A mapped file copied over in place (the same
        inode) changes what later reads return, and one truncated kills the reader (SIGBUS);
        pages the kernel dropped are read from disk again. Held, none of that reaches it."""
        held = np.array(self._values)  # (one copy: the modes in the process's own memory)
        for k in np.flatnonzero(~self._mode_ok):
            if mode_crc(held[k]) != int(self._crc[k]):
                self._damaged(f"mode {k} is not what the build wrote (its CRC-32)")
        self._mode_ok[:] = True
        step = max(1, 2**20 // (12 * len(self)))  # (nodes a slab: every mode at them about a megabyte)
        for start in range(0, self.shape[1], step):
            nodes = np.arange(start, min(start + step, self.shape[1]))
            self.check_nodes(nodes, held[:, nodes[0] : nodes[-1] + 1, :])
        self._values, self._mapping = held, None

    def _damaged(self, problem: str):
        raise InputError(f"ATLAS: '{self._folder}' is damaged: {problem}; build it again (or copy it again)")


def _whole(key) -> bool:
    """An index that takes a whole axis (``:``)."""
    return isinstance(key, slice) and key == slice(None)
