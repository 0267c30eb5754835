"""The whole-file checksum of a stored set, kept in the file's HDF5 user block.

A stored set begins with a user block of :data:`USERBLOCK` bytes that the HDF5 library
skips (its superblock follows at byte 512). :class:`~lcpbench.sets.SetWriter` writes into
it one line, ``lcpbench.set file-sha256 <hex> bytes <count>``: the SHA-256 and the length
of everything after the user block. So every byte of the set, its attributes, group
structure and HDF5 headers as well as its data, is inside one checksum, and the reader
checks it with plain Python reads before the HDF5 library parses anything: a changed bit
anywhere is a :class:`~lcpbench.sets.StoredSetError`, never a crash of the HDF5 library on
a damaged header nor an attribute changed silently.

Files written before the checksum (no user block) still load, with a warning once per
file and process: their datasets keep their own checksums, but their attributes are
unverified. :func:`lcpbench.sets.seal_set` adds the checksum to such a file after
verifying every dataset.
"""

from __future__ import annotations

import hashlib
import os
import re
import warnings
from pathlib import Path
from typing import Optional

from lcpbench.sets.common import PathLike, StoredSetError, _err

__all__ = ["USERBLOCK", "seal_image", "check_seal", "warn_unsealed"]

#: Bytes of the user block at the start of a stored set (HDF5 needs a power of two >= 512).
USERBLOCK = 512
_SIGNATURE = b"\x89HDF\r\n\x1a\n"
_HEADER = re.compile(rb"^lcpbench\.set file-sha256 ([0-9a-f]{64}) bytes ([0-9]{1,15})\n\x00*$")
_CHUNK = 1 << 20
# Files verified in this process: (device, inode, size, mtime) -> path; a file replaced
# or touched since is verified again.
_VERIFIED: dict[tuple, str] = {}
_WARNED: set[str] = set()


def seal_image(image: bytes) -> bytes:
    """``image`` (an HDF5 file with a user block of :data:`USERBLOCK` bytes) with its
    checksum line written into the user block."""
    if image[USERBLOCK:USERBLOCK + len(_SIGNATURE)] != _SIGNATURE:
        raise ValueError("the HDF5 image has no user block of 512 bytes to seal")
    body = memoryview(image)[USERBLOCK:]
    line = (f"lcpbench.set file-sha256 {hashlib.sha256(body).hexdigest()} "
            f"bytes {len(body)}\n").encode()
    return line.ljust(USERBLOCK, b"\x00") + bytes(body)


def _digest_after_block(fh, size: int) -> str:
    h = hashlib.sha256()
    fh.seek(USERBLOCK)
    left = size - USERBLOCK
    while left > 0:
        chunk = fh.read(min(_CHUNK, left))
        if not chunk:
            break
        h.update(chunk)
        left -= len(chunk)
    return h.hexdigest()


def check_seal(path: PathLike, generator: Optional[str] = None) -> bool:
    """Verify the whole-file checksum of the stored set at ``path`` before HDF5 reads it.

    Returns
    -------
    bool
        True when the file carries a checksum and it matches; False for a file without
        one (a set written before sets carried one, or not an HDF5 file at all).

    Raises
    ------
    StoredSetError
        The checksum does not match, or the user block holds a damaged checksum line.
    """
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            st = os.fstat(fh.fileno())
            key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
            if _VERIFIED.get(key) == str(p):
                return True
            head = fh.read(USERBLOCK + len(_SIGNATURE))
            if head[:len(_SIGNATURE)] == _SIGNATURE:       # no user block: an older set
                return False
            block, signature = head[:USERBLOCK], head[USERBLOCK:]
            m = _HEADER.match(block)
            if m is None:
                if signature == _SIGNATURE:
                    raise _err(p, "the file checksum line in its first 512 bytes is damaged",
                               generator=generator)
                return False        # not an HDF5 set at all: the HDF5 open says what it is
            stored, count = m.group(1).decode(), int(m.group(2))
            if count != st.st_size - USERBLOCK:
                raise _err(p, f"the file has {st.st_size - USERBLOCK} bytes after its "
                              f"checksum line, which records {count}: the file is "
                              "truncated or corrupted", generator=generator)
            got = _digest_after_block(fh, st.st_size)
    except OSError as exc:
        raise StoredSetError(f"{p}: cannot read the file ({exc.strerror or exc})",
                             path=p) from None
    if got != stored:
        raise _err(p, f"file checksum mismatch (sha256 {got[:12]}..., recorded "
                      f"{stored[:12]}...): a byte of the set (its data, attributes or HDF5 "
                      "structure) was changed or corrupted", generator=generator)
    _VERIFIED[key] = str(p)
    return True


def warn_unsealed(p: Path) -> None:
    """Warn, once per file and process, that the set at ``p`` carries no file checksum."""
    if str(p) in _WARNED:
        return
    _WARNED.add(str(p))
    warnings.warn(f"{p}: written before stored sets carried a file checksum, so its "
                  "attributes are not verified (its datasets are); add the checksum with "
                  "lcpbench.sets.seal_set(path), or regenerate the set", UserWarning,
                  stacklevel=4)
