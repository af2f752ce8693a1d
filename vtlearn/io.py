"""Point-cloud and mesh I/O.

Clouds: ``.ply``, ``.pcd`` (Open3D), ``.xyz`` / ``.txt`` / ``.csv`` (whitespace or comma separated, ``#``
comments and a header row skipped), ``.npy`` (an ``(N, k)`` array) and ``.npz`` (key ``points``, optional
``normals``; loaded with ``allow_pickle=False``). In the text and ``.npy`` formats the first three of k >= 3
columns are x y z, in metres; with k >= 6 the next three are the normals, further columns (intensity, ...) are
ignored. A ``.ply`` with faces but no point data reads as its vertices (:func:`read_geometry` samples the
surface instead).
Meshes: ``.obj``, ``.ply``, ``.stl``, ``.off`` (trimesh).

Every reader raises ``FileNotFoundError`` for a missing file and ``ValueError`` naming the file for an
unreadable, empty or malformed one.
"""

from __future__ import annotations

import glob
import hashlib
import os
import re
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from vtlearn.validation import as_int, as_points

__all__ = [
    "CLOUD_SUFFIXES",
    "MESH_SUFFIXES",
    "read_cloud",
    "read_cloud_with_normals",
    "write_cloud",
    "read_mesh",
    "write_mesh",
    "read_geometry",
    "read_poses",
    "atomic_write_npz",
    "sha256_file",
]

CLOUD_SUFFIXES = (".ply", ".pcd", ".xyz", ".txt", ".csv", ".npy", ".npz")
MESH_SUFFIXES = (".obj", ".ply", ".stl", ".off")


def _existing(path) -> Path:
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such file")
    if not p.is_file():
        raise ValueError(f"{p}: is not a regular file")
    return p


def _validated(points, normals, p: Path, allow_empty: bool = False):
    try:
        pts = as_points(points, "points", min_points=0 if allow_empty else 1)
    except ValueError as exc:
        raise ValueError(f"{p}: malformed point cloud ({str(exc).removeprefix('points: ')})") from None
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64)
        if normals.shape != pts.shape or not np.isfinite(normals).all():
            normals = None
    return pts, normals


def _numeric(row: list[str]) -> bool:
    try:
        [float(v) for v in row]
    except ValueError:
        return False
    return True


def read_cloud_with_normals(path, allow_empty: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """Read a point cloud and its normals, if the file has them.

    A cloud of no points (a saved ``(0, 3)`` array) is a ``ValueError`` unless ``allow_empty``: then it reads
    as ``(0, 3)``, as a frame in which a sensor saw nothing does.

    Shapes:
        output: points ``(N, 3)`` float64, normals ``(N, 3)`` or ``None``.
    """
    p = _existing(path)
    suffix = p.suffix.lower()
    if suffix not in CLOUD_SUFFIXES:
        raise ValueError(f"{p}: unsupported cloud format {suffix!r}; expected one of {CLOUD_SUFFIXES}")
    normals = None
    try:
        if suffix in (".ply", ".pcd"):
            import open3d as o3d

            pcd = o3d.io.read_point_cloud(str(p), format="auto")
            pts = np.asarray(pcd.points)
            if len(pts) == 0 and suffix == ".ply":
                # a mesh-only .ply: fall back to its vertices
                import trimesh

                geom = trimesh.load(str(p), process=False)
                pts = np.asarray(getattr(geom, "vertices", np.empty((0, 3))))
            elif pcd.has_normals():
                normals = np.asarray(pcd.normals)
        elif suffix in (".xyz", ".txt", ".csv"):
            text = p.read_text().replace(",", " ")
            rows = [r.split() for r in text.splitlines() if r.strip() and not r.lstrip().startswith("#")]
            if rows and not _numeric(rows[0]):
                rows = rows[1:]  # a header row (x y z ...)
            if not rows:
                raise ValueError("no data rows")
            width = {len(r) for r in rows}
            if len(width) != 1 or min(width) < 3:
                raise ValueError(f"rows have inconsistent or too few columns: {sorted(width)}")
            arr = np.array(rows, dtype=np.float64)
            pts = arr[:, :3]
            normals = arr[:, 3:6] if arr.shape[1] >= 6 else None
        elif suffix == ".npy":
            arr = np.load(p, allow_pickle=False)
            if arr.ndim != 2 or arr.shape[1] < 3:
                raise ValueError(f"expected an (N, k) array with k >= 3 columns (x y z first), got "
                                 f"{arr.shape}")
            pts, normals = arr[:, :3], (arr[:, 3:6] if arr.shape[1] >= 6 else None)
        else:  # .npz
            with np.load(p, allow_pickle=False) as data:
                if "points" not in data.files:
                    raise ValueError(f"no 'points' array (keys: {data.files})")
                pts = data["points"]
                normals = data["normals"] if "normals" in data.files else None
    except FileNotFoundError:
        raise
    except ValueError as exc:
        if str(exc).startswith(str(p)):
            raise
        raise ValueError(f"{p}: cannot read point cloud ({exc})") from None
    except Exception as exc:  # noqa: BLE001 - any parser failure becomes a clear error naming the file
        raise ValueError(f"{p}: cannot read point cloud ({type(exc).__name__}: {exc})") from None
    return _validated(pts, normals, p, allow_empty)


def read_cloud(path, allow_empty: bool = False) -> np.ndarray:
    """Read a point cloud (formats in the module docstring; a mesh file is :func:`read_geometry`'s). A cloud
    of no points is refused unless ``allow_empty`` (:func:`read_cloud_with_normals`).

    Shapes: output ``(N, 3)`` float64."""
    return read_cloud_with_normals(path, allow_empty)[0]


def write_cloud(path, points, normals=None) -> Path:
    """Write a point cloud (format from the suffix); parent folders are created.

    Shapes:
        points: ``(N, 3)``; normals: ``(N, 3)`` or ``None``.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in CLOUD_SUFFIXES:
        raise ValueError(f"path: unsupported cloud format {suffix!r}; expected one of {CLOUD_SUFFIXES}")
    pts = as_points(points, "points")
    nrm = None if normals is None else as_points(normals, "normals", min_points=len(pts))
    if nrm is not None and len(nrm) != len(pts):
        raise ValueError(f"normals: expected {len(pts)} normals, got {len(nrm)}")
    p.parent.mkdir(parents=True, exist_ok=True)
    if suffix in (".ply", ".pcd"):
        import open3d as o3d

        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
        if nrm is not None:
            pcd.normals = o3d.utility.Vector3dVector(nrm)
        if not o3d.io.write_point_cloud(str(p), pcd):
            raise ValueError(f"{p}: Open3D could not write the file")
    elif suffix in (".xyz", ".txt", ".csv"):
        arr = pts if nrm is None else np.hstack([pts, nrm])
        np.savetxt(p, arr, fmt="%.9g", delimiter="," if suffix == ".csv" else " ")
    elif suffix == ".npy":
        np.save(p, pts if nrm is None else np.hstack([pts, nrm]))
    else:
        arrays = {"points": pts} if nrm is None else {"points": pts, "normals": nrm}
        np.savez(p, **arrays)
    return p


def read_mesh(path):
    """Read a triangle mesh with trimesh (scenes are concatenated into one mesh).

    Raises:
        FileNotFoundError: missing file.
        ValueError: unsupported suffix, unreadable file, or a mesh without faces / with zero area.
    """
    import trimesh

    p = _existing(path)
    suffix = p.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise ValueError(f"{p}: unsupported mesh format {suffix!r}; expected one of {MESH_SUFFIXES}")
    try:
        geom = trimesh.load(str(p), force="mesh", process=True)
    except Exception as exc:  # noqa: BLE001
        raise ValueError(f"{p}: cannot read mesh ({type(exc).__name__}: {exc})") from None
    if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
        raise ValueError(f"{p}: file holds no triangle faces")
    if not np.isfinite(geom.vertices).all():
        raise ValueError(f"{p}: mesh has NaN or inf vertices")
    if not geom.area > 0:
        raise ValueError(f"{p}: mesh is degenerate (zero surface area)")
    return geom


def write_mesh(path, mesh) -> Path:
    """Write a trimesh mesh; the format comes from the suffix (.obj, .ply, .stl, .off)."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise ValueError(f"path: unsupported mesh format {suffix!r}; expected one of {MESH_SUFFIXES}")
    if len(getattr(mesh, "faces", [])) == 0:
        raise ValueError("mesh: has no faces")
    p.parent.mkdir(parents=True, exist_ok=True)
    mesh.export(str(p))
    return p


def read_geometry(path, n_points: int = 1024, seed: int | None = 0) -> np.ndarray:
    """Read ``path`` as a point cloud: cloud formats as they are, meshes sampled uniformly on the surface.

    A ``.ply`` with faces is treated as a mesh. Shapes: output ``(N, 3)`` (``n_points`` for meshes).

    Args:
        path: a cloud (``.npy``, ``.ply`` without faces, ...) or mesh (``.obj``, ``.stl``, ``.off``, ``.ply``
            with faces) file.
        n_points: points sampled on a mesh surface, an integer ``>= 1``. Ignored for cloud files, which are
            returned with all their points (not subsampled); it is still validated.
        seed: seed of the mesh surface sampling.
    """
    n_points = as_int(n_points, "n_points")
    p = _existing(path)
    suffix = p.suffix.lower()
    is_mesh = suffix in (".obj", ".stl", ".off")
    if suffix == ".ply":
        import trimesh

        try:
            geom = trimesh.load(str(p), process=False)
            is_mesh = isinstance(geom, trimesh.Trimesh) and len(geom.faces) > 0
        except Exception:  # noqa: BLE001 - let read_cloud report it
            is_mesh = False
    if is_mesh:
        from vtlearn.geometry.sampling import sample_surface

        return sample_surface(read_mesh(p), n_points, seed)[0]
    return read_cloud(p)


POSE_FORMATS = "a .npy (N, 4, 4) or (4, 4) array, a JSON nested list, or text of 4x4 blocks stacked (4N x 4)"


def read_poses(path, name: str, *, n: int | None = None) -> np.ndarray:
    """Rigid poses ``T_a_b`` from a file, each checked and snapped to the nearest rotation
    (:func:`vtlearn.validation.as_stored_transform`, so a file written with 4 decimals reads).

    Formats: ``.npy`` (``(N, 4, 4)`` or ``(4, 4)``, ``allow_pickle=False``), ``.json`` (a nested list of the
    same shapes) or any other suffix as whitespace-separated text, one 4x4 block after another. Shapes:
    output ``(N, 4, 4)`` float64.

    Args:
        path: the file.
        name: what the user calls it (a command-line flag such as ``--poses``); every error names it.
        n: the number of poses required, or ``None`` for any number ``>= 1``.

    Raises:
        FileNotFoundError: no file at ``path``.
        ValueError: an unreadable file, no numbers, the wrong count or shape, or a pose that is not rigid.
    """
    import json
    import warnings

    from vtlearn.validation import as_stored_transform

    p = Path(path)
    want = f"{'one' if n == 1 else n if n is not None else 'N'} pose{'' if n == 1 else 's'} as {POSE_FORMATS}"
    if not p.is_file():
        raise FileNotFoundError(f"{name}: no file at {p}; need {want}")
    suffix = p.suffix.lower()
    try:
        if suffix == ".npy":
            arr = np.load(p, allow_pickle=False)
        elif suffix == ".json":
            arr = json.loads(p.read_text())
        else:
            with warnings.catch_warnings():  # an empty file: numpy warns, then the size check below refuses
                warnings.simplefilter("ignore", UserWarning)
                arr = np.loadtxt(p, ndmin=2)
        arr = np.asarray(arr, dtype=np.float64)
    except (ValueError, TypeError, OSError) as exc:  # json.JSONDecodeError is a ValueError
        raise ValueError(f"{name}: cannot read {p} ({exc}); need {want}") from None
    if arr.size == 0:
        raise ValueError(f"{name}: {p} holds no numbers; need {want}")
    if arr.ndim == 2 and arr.shape[1] == 4 and arr.shape[0] % 4 == 0:
        arr = arr.reshape(-1, 4, 4)  # (4, 4), or text blocks stacked
    if arr.ndim != 3 or arr.shape[1:] != (4, 4) or (n is not None and len(arr) != n):
        shown = arr.shape if arr.ndim != 3 or arr.shape[1:] != (4, 4) else f"{len(arr)} poses"
        raise ValueError(f"{name}: need {want}, got {shown if isinstance(shown, str) else f'shape {shown}'}")
    if len(arr) == 1:
        return as_stored_transform(arr[0], name)[None]
    return np.stack([as_stored_transform(T, f"{name} (pose {i})") for i, T in enumerate(arr)])


def _temporary_of(p: Path, pid: int) -> Path:
    """The temporary file that :func:`atomic_path` in process ``pid`` writes for ``p``:
    ``.<stem>.tmp-<pid><suffix>``, which ``_TEMPORARIES[0]`` reads back."""
    return p.with_name(f".{p.stem}.tmp-{pid}{p.suffix}")


_TEMPORARIES = (
    re.compile(r"\..+\.tmp-(\d+)(\.[^.]*)?"),  # _temporary_of's ".<stem>.tmp-<pid><suffix>"
    re.compile(r".+\.tmp(\d+)"),  # the dataset writer's "<name>.tmp<pid>", before atomic_path
)


def _writer_pid(name: str, patterns=_TEMPORARIES) -> int | None:
    """The writer's pid in a temporary file's ``name``, by the first of ``patterns`` it matches, or None."""
    for pattern in patterns:
        m = pattern.fullmatch(name)
        if m:
            return int(m.group(1))
    return None


@contextmanager
def atomic_path(path) -> Iterator[Path]:
    """A temporary path beside ``path`` to write into, renamed over ``path`` (``os.replace``) when the block
    ends without an exception and removed whatever happens, so a reader never sees a partial file and a
    failed write leaves nothing behind. The temporary file keeps ``path``'s suffix (matplotlib and
    ``np.savez`` infer the format from it); parent folders are created.

    Example: ``with atomic_path("x.ckpt") as tmp: torch.save(obj, tmp)``.
    """
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = _temporary_of(p, os.getpid())
    try:
        yield tmp
        os.replace(tmp, p)
    finally:
        tmp.unlink(missing_ok=True)


def _writer_ended(pid: int) -> bool:
    """Whether process ``pid`` (the writer named in a temporary file's name) has ended: not this process,
    and signal 0 finds no such process (one of another user exists). A number that no process can have
    (0 would signal this process group) is not taken for an ended writer."""
    if pid == os.getpid() or not 0 < pid < 2**31:
        return False
    try:
        os.kill(pid, 0)  # signal 0: only asks whether the process exists
    except ProcessLookupError:
        return True
    except PermissionError:  # it exists, under another user
        return False
    return False


def _remove_ended(candidates, pid_of) -> list[Path]:
    removed = []
    for tmp in sorted(candidates):
        pid = pid_of(tmp.name)
        if pid is not None and _writer_ended(pid):
            tmp.unlink(missing_ok=True)
            removed.append(tmp)
    return removed


def remove_stale_temporaries(path) -> list[Path]:
    """Remove the temporary files of :func:`atomic_path` beside ``path`` whose writing process is no longer
    running (a SIGKILL between the write and the rename leaves one) and return them. Those of running
    processes, this one included, are kept; so is everything on a system without POSIX process signals.
    """
    p = Path(path)
    if os.name != "posix" or not p.parent.is_dir():
        return []

    def pid_of(name: str) -> int | None:  # only p's own temporaries, not another stem's
        pid = _writer_pid(name, _TEMPORARIES[:1])
        return pid if pid is not None and _temporary_of(p, pid).name == name else None

    return _remove_ended(p.parent.glob(f".{glob.escape(p.stem)}.tmp-*"), pid_of)


def remove_stale_temporaries_in(folder) -> list[Path]:
    """:func:`remove_stale_temporaries` for every file directly in ``folder``: the :func:`atomic_path`
    temporaries (and the ``<name>.tmp<pid>`` ones of the dataset writer from before it) whose writer has
    ended, as a dataset folder's shards, side files and JSON leave them. Those of running writers (another
    process generating into the same folder) are kept, and so is every file of another name (a user's
    ``notes.tmp.txt``). Nothing is removed on a system without POSIX process signals. ``folder`` must be a
    path (``str`` or ``os.PathLike``); one that is no folder holds nothing to remove."""
    if not isinstance(folder, str | os.PathLike):
        raise ValueError(f"folder: need a path (str or os.PathLike), got {type(folder).__name__}")
    folder = Path(folder)
    if os.name != "posix" or not folder.is_dir():
        return []

    return _remove_ended((f for f in folder.glob("*.tmp*") if f.is_file()), _writer_pid)


def atomic_write_npz(path, *, compress: bool = False, **arrays) -> Path:
    """Write an ``.npz`` atomically and byte-reproducibly.

    The arrays go to a temporary file in the same folder, which is fsync'ed and then renamed over ``path``
    (``os.replace``), so a reader never sees a partial file. Zip entries carry a fixed timestamp and are
    written in sorted key order: equal data always gives equal bytes, hence equal sha256 sums in dataset
    manifests (``np.savez`` stamps the current time instead). Object arrays are refused, so every file
    loads with ``allow_pickle=False``.

    Args:
        path: destination file.
        compress: deflate the entries (deterministic for a given zlib).
        **arrays: name -> array.
    """
    import zipfile

    p = Path(path)
    for k, v in arrays.items():
        if np.asarray(v).dtype == object:
            raise ValueError(f"{k}: object arrays cannot be stored (files must load with allow_pickle=False)")
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with atomic_path(p) as tmp, open(tmp, "wb") as fh:
        with zipfile.ZipFile(fh, "w", compression=method) as zf:
            for key in sorted(arrays):
                info = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
                info.compress_type = method
                info.external_attr = 0o644 << 16
                with zf.open(info, "w", force_zip64=True) as f:
                    np.lib.format.write_array(f, np.ascontiguousarray(arrays[key]), allow_pickle=False)
        fh.flush()
        os.fsync(fh.fileno())
    return p


def sha256_file(path) -> str:
    """The SHA-256 (hex) of the file at ``path``, read in 1 MiB chunks: the checksums of the dataset manifests
    and of the benches' journals (:mod:`vtlearn.bench_journal`)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()
