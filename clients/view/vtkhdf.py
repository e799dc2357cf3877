"""A transient VTKHDF file (VTK's HDF5 format, read by ParaView 5.12+ and VTK 9.3+): one
``UnstructuredGrid`` whose topology is written once and whose points and point/cell arrays are
appended frame by frame (VTKHDF specification, "Temporal Data": every ``Steps`` offset of the
connectivity and of the part is 0, the points' and arrays' offsets advance by one frame). Written with h5py,
``buffer`` frames at a time (one write per array for them); the file is valid after every flush."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

VERSION = (2, 2)


CHUNK_BYTES = 1 << 16     # 64 KiB a chunk: few chunks (HDF5's index of them stays small) on long runs
CHUNK_CACHE = 4 * CHUNK_BYTES   # a dataset's chunk cache: the chunk being filled and a flush's worth (h5py: 1 MiB)
METADATA_CACHE = 1 << 20        # a file's metadata cache at most (HDF5: grows to 32 MiB, the chunk index of a long run)


def _growing(group: h5py.Group, name: str, width: int | None, dtype) -> h5py.Dataset:
    """An empty dataset growing along its first axis, in chunks of about CHUNK_BYTES."""
    shape, maxshape = ((0,), (None,)) if width is None else ((0, width), (None, width))
    rows = max(1, CHUNK_BYTES // (8 * (width or 1)))
    chunks = (rows,) if width is None else (rows, width)
    return group.create_dataset(name, shape=shape, maxshape=maxshape, dtype=dtype, chunks=chunks)


def _append(ds: h5py.Dataset, values) -> None:
    values = np.asarray(values, ds.dtype)
    n = ds.shape[0]
    ds.resize(n + values.shape[0], axis=0)
    ds[n:] = values


class TransientGrid:
    """One part's transient file. ``point_arrays`` / ``cell_arrays`` / ``field_arrays``: name ->
    components (1, 3 or 6) of the arrays every frame gives (a field array: one tuple a frame)."""

    def __init__(self, path: str | Path, connectivity: np.ndarray, offsets: np.ndarray, types: np.ndarray,
                 n_points: int, point_arrays: dict[str, int], cell_arrays: dict[str, int],
                 field_arrays: dict[str, int] | None = None, buffer: int = 16):
        self.path = Path(path)
        self.n_points, self.n_cells = int(n_points), int(types.size)
        self.point_arrays, self.cell_arrays = dict(point_arrays), dict(cell_arrays)
        self.field_arrays = dict(field_arrays or {})
        self.frames = 0                    # frames in the file
        self.buffer = max(1, int(buffer))
        self._pending: dict[str, list] = {"Values": []}
        self._file = h5py.File(self.path, "w", rdcc_nbytes=CHUNK_CACHE)
        config = self._file.id.get_mdc_config()
        config.max_size, config.min_size, config.initial_size, config.set_initial_size = (
            METADATA_CACHE, METADATA_CACHE // 4, METADATA_CACHE // 2, True)
        self._file.id.set_mdc_config(config)
        root = self._file.create_group("VTKHDF", track_order=True)
        root.attrs["Version"] = np.asarray(VERSION, np.int64)
        root.attrs.create("Type", np.bytes_("UnstructuredGrid"))
        root.create_dataset("Connectivity", data=np.asarray(connectivity, np.int64))
        root.create_dataset("Offsets", data=np.asarray(offsets, np.int64))
        root.create_dataset("Types", data=np.asarray(types, np.uint8))
        self._points = _growing(root, "Points", 3, "f8")
        for name, count in (("NumberOfPoints", self.n_points), ("NumberOfCells", self.n_cells),
                            ("NumberOfConnectivityIds", int(np.asarray(connectivity).size))):
            root.create_dataset(name, data=np.array([count], np.int64))   # one part, the same every frame
        self._data = {}
        for group, arrays in (("PointData", self.point_arrays), ("CellData", self.cell_arrays),
                              ("FieldData", self.field_arrays)):
            g = root.create_group(group)
            for name, width in arrays.items():
                self._data[name] = _growing(g, name, None if width == 1 else width, "f8")
        steps = root.create_group("Steps")
        self._steps = steps
        self._step = {n: _growing(steps, n, None, "i8") for n in ("PartOffsets", "NumberOfParts", "PointOffsets")}
        self._step["Values"] = _growing(steps, "Values", None, "f8")
        self._step.update({n: _growing(steps, n, 1, "i8") for n in ("CellOffsets", "ConnectivityIdOffsets")})
        self._offsets = {}
        for group, arrays in (("PointDataOffsets", self.point_arrays), ("CellDataOffsets", self.cell_arrays),
                              ("FieldDataOffsets", self.field_arrays)):
            g = steps.create_group(group)
            for name in arrays:
                self._offsets[name] = _growing(g, name, None, "i8")
        sizes = steps.create_group("FieldDataSizes")
        self._sizes = {name: _growing(sizes, name, 2, "i8") for name in self.field_arrays}
        steps.attrs["NSteps"] = 0

    def append(self, t: float, points: np.ndarray, point_data: dict[str, np.ndarray],
               cell_data: dict[str, np.ndarray], field_data: dict[str, np.ndarray] | None = None) -> None:
        """One frame at time ``t``: its points (P, 3) and every declared array (held until
        ``buffer`` frames are pending, then written together)."""
        k = self.frames + len(self._pending["Values"])
        rows = {"Points": np.array(points, float), "Values": [t], "PartOffsets": [0], "NumberOfParts": [1],
                "PointOffsets": [k * self.n_points], "CellOffsets": [[0]], "ConnectivityIdOffsets": [[0]]}
        for name, value in (*point_data.items(), *cell_data.items()):
            rows[name] = np.array(value, float)   # a copy: the caller may reuse its buffers
            rows["offset:" + name] = [k * (self.n_points if name in point_data else self.n_cells)]
        for name, value in (field_data or {}).items():
            rows[name] = np.reshape(value, (1, -1))
            rows["offset:" + name] = [k]
            rows["size:" + name] = [[self.field_arrays[name], 1]]
        for name, value in rows.items():
            self._pending.setdefault(name, []).append(value)
        if len(self._pending["Values"]) >= self.buffer:
            self.flush()

    def flush(self) -> None:
        """Write the pending frames (the file then holds every frame appended)."""
        n = len(self._pending.get("Values", ()))
        if n == 0:
            return
        for name, values in self._pending.items():
            kind, _, array = name.partition(":")
            target = {"offset": self._offsets, "size": self._sizes}.get(kind, {}).get(array) if array else None
            if target is None:
                target = self._points if name == "Points" else self._step.get(name, self._data.get(name))
            _append(target, np.concatenate([np.asarray(v) for v in values]))
        self._pending = {"Values": []}
        self.frames += n
        self._steps.attrs["NSteps"] = self.frames
        self._file.flush()

    def close(self) -> None:
        self.flush()
        self._file.close()

    def __enter__(self) -> "TransientGrid":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
