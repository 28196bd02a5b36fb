"""Reading untrusted ``.npy`` and ``.npz`` files strictly: no code from a data file, no
allocation beyond the memory there is, one clear error for every damaged file.

A file a user is handed (a press pack, a recording's frames, a calibration bundle, a flat
field) is data, never code, and its header is read before its data:

* the magic bytes must say ``.npy`` (``\\x93NUMPY``) or zip archive (``PK``);
* each array's header is parsed with :mod:`numpy.lib.format` (format 1.0 or 2.0, at most
  :data:`MAX_HEADER_SIZE` bytes of header) before any of its data is read;
* an object dtype (a pickled member) is refused, naming the file and the member: nothing is
  unpickled, ever;
* an array whose declared size (shape × item size, summed over the members read) is above
  :func:`array_size_limit` is refused, naming the declared size and the limit, before
  anything of that size is allocated; so is an array declaring more data than the file holds;
* every other way a file can be damaged (truncated, random bytes, a bad zip directory, a bad
  header, a member that is not a ``.npy`` array) becomes one :class:`~thintact_sdk.errors.ThinTactError`
  of the caller's choice naming the file and the member.

Callers pass the error type their domain raises (``RecordingError``, ``CalibrationError``,
…); :class:`ArrayFileError` is the default.
"""

from __future__ import annotations

import contextlib
import math
import os
import struct
import tokenize
import zipfile
import zlib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np

from thintact_sdk.errors import ThinTactError

NPY_MAGIC = b"\x93NUMPY"
ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")
MAX_HEADER_SIZE = 10_000
"""Largest ``.npy`` header accepted (numpy's own default bound), in bytes."""
MEMORY_FRACTION = 0.5
"""Share of the available memory (``MemAvailable``) one file's arrays may declare."""
MIN_LIMIT_BYTES = 256 * 2**20
"""The limit never drops below this, so that a busy host still reads ordinary files."""


class ArrayFileError(ThinTactError):
    """An ``.npy``/``.npz`` file is missing, damaged, holds pickled objects or declares more
    data than this host can hold; the message names the file and the member."""


def _damaged_errors() -> tuple[type[BaseException], ...]:
    errs: list[type[BaseException]] = [
        OSError, ValueError, EOFError, KeyError, IndexError, TypeError, OverflowError,
        struct.error, zlib.error, zipfile.BadZipFile, zipfile.LargeZipFile,
        NotImplementedError, RuntimeError, MemoryError, SyntaxError, tokenize.TokenError,
    ]
    with contextlib.suppress(ImportError):  # Python may be built without lzma
        import lzma

        errs.append(lzma.LZMAError)
    return tuple(errs)


_DAMAGED = _damaged_errors()
"""What numpy and zipfile raise for a damaged file (zipfile: RuntimeError for an encrypted
member, NotImplementedError for an unknown compression, struct.error for a torn directory;
numpy's header parser: tokenize.TokenError for a torn header)."""


def available_memory_bytes() -> int:
    """Memory available to a new allocation, in bytes: ``MemAvailable`` of ``/proc/meminfo``,
    else the free physical pages (``SC_AVPHYS_PAGES``), else all physical pages."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    for name in ("SC_AVPHYS_PAGES", "SC_PHYS_PAGES"):
        try:
            pages, size = os.sysconf(name), os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            continue
        if pages > 0 and size > 0:
            return int(pages) * int(size)
    return 4 * 2**30


def array_size_limit() -> int:
    """The most bytes of arrays one file may declare: :data:`MEMORY_FRACTION` of
    :func:`available_memory_bytes`, at least :data:`MIN_LIMIT_BYTES`."""
    return max(int(available_memory_bytes() * MEMORY_FRACTION), MIN_LIMIT_BYTES)


def format_bytes(n: int) -> str:
    """``n`` bytes in binary units (``3.0 TiB``)."""
    value = float(n)
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if value < 1024 or unit == "PiB":
            return f"{n} B" if unit == "B" else f"{value:.1f} {unit}"
        value /= 1024
    raise AssertionError("unreachable")


@dataclass(frozen=True)
class ArrayHeader:
    """A ``.npy`` header as declared (nothing of the data read yet).

    Attributes
    ----------
    shape, dtype, fortran_order
        As the header declares them.
    data_offset
        Bytes from the start of the ``.npy`` stream to its data.
    """

    shape: tuple[int, ...]
    dtype: np.dtype
    fortran_order: bool
    data_offset: int

    @property
    def nbytes(self) -> int:
        """Declared data size in bytes (exact, no overflow)."""
        return math.prod(self.shape) * self.dtype.itemsize

    def describe(self) -> str:
        """``2×3 float32`` (for messages)."""
        return f"{'×'.join(map(str, self.shape)) or 'scalar'} {self.dtype}"


def _where(path: Path, member: str | None) -> str:
    return f"{path}" if member is None else f"{path} member {member!r}"


def read_header(fp: IO[bytes], path: Path, member: str | None = None,
                error: type[ThinTactError] = ArrayFileError) -> ArrayHeader:
    """Parse the ``.npy`` header at the current position of ``fp`` (left at the data).

    Raises
    ------
    error
        Naming ``path`` and ``member``: not a ``.npy`` stream, a format other than 1.0/2.0, a
        damaged header, or a negative dimension.
    """
    where = _where(path, member)
    start = fp.tell()
    magic = fp.read(len(NPY_MAGIC))
    if magic != NPY_MAGIC:
        raise error(f"{where} is not a .npy array (no \\x93NUMPY magic)")
    fp.seek(start)
    try:
        version = np.lib.format.read_magic(fp)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(
                fp, max_header_size=MAX_HEADER_SIZE)
        elif version == (2, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(
                fp, max_header_size=MAX_HEADER_SIZE)
        else:
            raise error(f"{where}: .npy format version {version[0]}.{version[1]} is not read "
                        "(1.0 and 2.0 are)")
    except ThinTactError:
        raise
    except _DAMAGED as err:
        raise error(f"{where}: damaged .npy header ({err})") from None
    if any(int(d) < 0 for d in shape):
        raise error(f"{where}: .npy header declares a negative dimension {shape}")
    return ArrayHeader(tuple(int(d) for d in shape), dtype, bool(fortran), fp.tell() - start)


def check_header(head: ArrayHeader, path: Path, member: str | None = None, *,
                 error: type[ThinTactError] = ArrayFileError, kinds: str | None = None,
                 data_bytes: int | None = None, already: int = 0,
                 limit: int | None = None) -> None:
    """Refuse a header before its data is read.

    Parameters
    ----------
    kinds
        Allowed ``dtype.kind`` letters (``"fiu"``); None: any dtype without objects.
    data_bytes
        Bytes of data the file holds after the header (None: unknown).
    already
        Bytes of arrays of the same file read before this one (they count towards the limit).
    limit
        Bytes; default :func:`array_size_limit`.

    Raises
    ------
    error
        An object dtype (pickled data), a kind outside ``kinds``, a declared size above the
        limit (naming both) or above ``data_bytes``.
    """
    where = _where(path, member)
    if head.dtype.hasobject:
        raise error(f"{where}: holds Python objects (dtype {head.dtype}), which would be "
                    "unpickled, i.e. run code from the file; refused (save plain arrays)")
    if kinds is not None and head.dtype.kind not in kinds:
        wanted = "a number array" if set(kinds) <= set("biufc") else "an array"
        raise error(f"{where}: dtype {head.dtype} is not {wanted} ({_kind_names(kinds)})")
    cap = array_size_limit() if limit is None else limit
    if already + head.nbytes > cap:
        more = f" (with {format_bytes(already)} of other arrays)" if already else ""
        raise error(f"{where}: declares a {head.describe()} array of {format_bytes(head.nbytes)}"
                    f"{more}, more than the {format_bytes(cap)} limit of this reader (set by "
                    "the available memory); refused before reading it")
    if data_bytes is not None and head.nbytes > data_bytes:
        raise error(f"{where}: declares a {head.describe()} array of {head.nbytes} bytes but "
                    f"holds {max(data_bytes, 0)} bytes of data (truncated)")


_KIND_NAMES = {"b": "bool", "i": "int", "u": "uint", "f": "float", "c": "complex",
               "U": "unicode text", "S": "bytes", "V": "void", "M": "datetime",
               "m": "timedelta"}


def _kind_names(kinds: str) -> str:
    names = [_KIND_NAMES.get(k, k) for k in kinds]
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} or {names[-1]}"


def read_npy(path: str | os.PathLike[str], *, what: str = "array",
             error: type[ThinTactError] = ArrayFileError, kinds: str | None = None,
             mmap: bool = False, limit: int | None = None) -> np.ndarray:
    """The array of an untrusted ``.npy`` file, header checked first (module docstring).

    Parameters
    ----------
    what
        What the file holds, for messages (``"scenes"``, ``"measurement"``).
    kinds
        Allowed ``dtype.kind`` letters, checked on the header; None: any non-object dtype.
    mmap
        Map the file read-only instead of reading it (the header is still checked, and the
        file must hold all the data it declares).
    limit
        Bytes; default :func:`array_size_limit` (not applied with ``mmap``: a mapping
        allocates nothing).

    Raises
    ------
    error
        Naming ``path``: missing, unreadable, not a ``.npy`` file, damaged or truncated, an
        object dtype, a kind outside ``kinds``, or a declared size above the limit.
    """
    p = Path(path)
    if not p.is_file():
        raise error(f"{what} file not found: {p}")
    try:
        with open(p, "rb") as f:
            head = read_header(f, p, None, error)
            size = os.fstat(f.fileno()).st_size
            check_header(head, p, None, error=error, kinds=kinds,
                         data_bytes=size - head.data_offset,
                         limit=2**63 if mmap else limit)
            if mmap:
                arr = np.load(p, mmap_mode="r", allow_pickle=False)
            else:
                f.seek(0)
                arr = np.lib.format.read_array(f, allow_pickle=False,
                                               max_header_size=MAX_HEADER_SIZE)
    except ThinTactError:
        raise
    except _DAMAGED as err:
        raise error(f"cannot read {what} {p} (truncated or damaged .npy file): "
                    f"{err.__class__.__name__}: {err}") from None
    return _checked(arr, head, p, None, error)


def _checked(arr: object, head: ArrayHeader, path: Path, member: str | None,
             error: type[ThinTactError]) -> np.ndarray:
    """``arr`` after checking that it is what the header declared."""
    if not isinstance(arr, np.ndarray) or arr.shape != head.shape or arr.dtype != head.dtype:
        raise error(f"{_where(path, member)}: read something other than the declared "
                    f"{head.describe()} array")
    return arr


def is_npz(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` starts with a zip archive's magic bytes (False when unreadable)."""
    try:
        with open(path, "rb") as f:
            return f.read(4) in ZIP_MAGIC
    except OSError:
        return False


def read_npz(path: str | os.PathLike[str], *, what: str = "arrays",
             error: type[ThinTactError] = ArrayFileError,
             members: Iterable[str] | None = None, optional: Iterable[str] = (),
             kinds: str | Mapping[str, str] | None = None,
             limit: int | None = None) -> dict[str, np.ndarray]:
    """Arrays of an untrusted ``.npz`` archive, each member's header checked before its data
    (module docstring).

    Parameters
    ----------
    what
        What the file holds, for messages (``"press pack"``, ``"filter"``).
    members
        Members that must be present (names without ``.npy``); None: every member.
    optional
        Members read when present.
    kinds
        Allowed ``dtype.kind`` letters: one string for every member, or per member (members
        not in the mapping: any non-object dtype).
    limit
        Bytes, for all members read together; default :func:`array_size_limit`.

    Returns
    -------
    dict
        ``{member: array}`` in the order asked for (archive order with ``members=None``);
        members not asked for are not read.

    Raises
    ------
    error
        Naming ``path`` and the member: missing, unreadable, not a zip archive, damaged or
        truncated, a missing member, a member that is not a ``.npy`` array, an object dtype,
        a kind outside ``kinds``, or declared sizes above the limit.
    """
    p = Path(path)
    try:
        found = p.is_file()
    except (OSError, ValueError) as err:  # a name too long for the file system, a NUL byte
        raise error(f"cannot read {what} {str(p)[:200]}: {getattr(err, 'strerror', None) or err}") from None
    if not found:
        raise error(f"{what} file not found: {p}")
    try:
        with open(p, "rb") as f:
            magic = f.read(4)
    except OSError as err:
        raise error(f"cannot read {what} {p}: {err.strerror or err}") from None
    if magic not in ZIP_MAGIC:
        raise error(f"{p} is not an .npz archive (expected the {what})")
    cap = array_size_limit() if limit is None else limit
    out: dict[str, np.ndarray] = {}
    member: str | None = None
    try:
        with zipfile.ZipFile(p) as zf:
            infos: dict[str, zipfile.ZipInfo] = {}
            for info in zf.infolist():
                key = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
                infos[key] = info
            if members is None:
                wanted = list(infos)
            else:
                wanted = list(members)
                missing = [k for k in wanted if k not in infos]
                if missing:
                    raise error(f"{p}: missing arrays {', '.join(missing)} (the {what} holds "
                                f"{', '.join(infos) or 'none'})")
            wanted += [k for k in optional if k in infos and k not in wanted]
            total = 0
            for member in wanted:
                info = infos[member]
                allowed = kinds if isinstance(kinds, str) or kinds is None else kinds.get(member)
                with zf.open(info) as fm:
                    head = read_header(fm, p, member, error)
                    check_header(head, p, member, error=error, kinds=allowed,
                                 data_bytes=info.file_size - head.data_offset,
                                 already=total, limit=cap)
                    total += head.nbytes
                    fm.seek(0)
                    arr = np.lib.format.read_array(fm, allow_pickle=False,
                                                   max_header_size=MAX_HEADER_SIZE)
                out[member] = _checked(arr, head, p, member, error)
    except ThinTactError:
        raise
    except _DAMAGED as err:
        where = _where(p, member) if member is not None else str(p)
        raise error(f"cannot read {what} {where} (truncated or damaged .npz file): "
                    f"{err.__class__.__name__}: {err}") from None
    return out
