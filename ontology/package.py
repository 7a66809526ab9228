"""RApp package format: build, inspect (without extracting) and safely unpack ``.rapp`` archives.

Archive format (``.rapp``): a gzip-compressed POSIX (pax) tar, built deterministically: entries
sorted by path with ``manifest.yaml`` (canonical YAML of the validated manifest) first and the
optional ``SIGNATURE`` last; only regular files (no directory entries), mode 0644, uid/gid 0,
empty owner names, mtime `FIXED_MTIME`, gzip header mtime 0 and no file name. The same source
directory and key therefore always yield the same bytes.

Signature scheme ``ed25519-sha256-v1``: the *content digest* is
``sha256(b"rapp-content-v1\\n" + b"".join(f"{path}\\t{size}\\t{sha256(file)}\\n"))`` over every
file except ``SIGNATURE``, sorted by path (so the manifest is covered, and the digest does not
depend on tar/gzip bytes). The publisher signs ``b"rapp-package-signature-v1\\0" + digest`` with
its ed25519 key. ``SIGNATURE`` is JSON ``{"scheme", "key_id", "public_key", "content_digest",
"signature"}`` with the raw public key and signature in base64 and ``key_id`` =
`public_key_id` (first 16 hex digits of sha256 of the raw public key). Readers recompute the
digest and verify with the embedded key: a bad signature is always refused; whether the key is
*trusted* is checked against the reader's ``trusted_keys`` (the Store records the embedded key
as the publisher's key; the Core passes its trusted keys with ``require_signature=True``).
"""
from __future__ import annotations

import base64
import binascii
import gzip
import hashlib
import io
import json
import os
import shutil
import stat
import tarfile
import tempfile
import zlib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from enum import Enum
from pathlib import Path, PurePosixPath

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey

from .errors import ErrorCode
from .manifest import (
    MANIFEST_NAMES,
    Manifest,
    ManifestError,
    entry_point_module_paths,
    load_manifest,
    manifest_format,
    parse_manifest,
)

SIGNATURE_NAME = "SIGNATURE"
SIGNATURE_SCHEME = "ed25519-sha256-v1"
PACKAGE_SUFFIX = ".rapp"
FIXED_MTIME = 315532800  # 1980-01-01T00:00:00Z
_CONTENT_PREFIX = b"rapp-content-v1\n"
_SIGN_PREFIX = b"rapp-package-signature-v1\0"
_SKIP_DIRS = {"__pycache__"}  # a RApp's tests are shipped: the Store builds it per robot type by them
_SKIP_SUFFIXES = (".pyc", ".pyo", PACKAGE_SUFFIX)
_MAX_PATH = 255
_MAX_SIGNATURE_SIZE = 4096
_HEADER_ALLOWANCE = 4096  # tar header/pax bytes allowed per entry on top of file contents

DEFAULT_MAX_SIZE = 16 * 1024 * 1024  # archive bytes
DEFAULT_MAX_TOTAL = 64 * 1024 * 1024  # sum of unpacked file sizes
DEFAULT_MAX_FILE = 16 * 1024 * 1024  # one unpacked file
DEFAULT_MAX_FILES = 1000


# ---------------------------------------------------------------------------------- errors
class PackageError(Exception):
    """Base of every package refusal; ``code`` is a short machine-readable reason."""

    code = ErrorCode.INVALID_PACKAGE


class CorruptArchiveError(PackageError):
    """Not a readable gzip/tar archive."""

    code = ErrorCode.CORRUPT


class PackageTooLargeError(PackageError):
    """Archive, one file or the unpacked total exceeds its limit."""

    code = ErrorCode.TOO_LARGE


class TooManyFilesError(PackageError):
    """More entries than allowed."""

    code = ErrorCode.TOO_MANY_FILES


class UnsafePathError(PackageError):
    """Entry name is absolute, contains '..', is malformed, duplicated or conflicting."""

    code = ErrorCode.UNSAFE_PATH


class UnsafeEntryError(PackageError):
    """Entry is not a regular file: symlink, hard link, device, fifo..."""

    code = ErrorCode.UNSAFE_ENTRY


class MissingManifestError(PackageError):
    """No ``manifest.yaml``/``manifest.json`` at the archive root."""

    code = ErrorCode.MISSING_MANIFEST


class InvalidManifestError(PackageError, ManifestError):
    """The manifest is present but invalid (message gives the field and reason)."""

    code = ErrorCode.INVALID_MANIFEST


class EntryPointError(PackageError):
    """An entry point's module is not in the archive."""

    code = ErrorCode.ENTRY_POINT_MISSING


class SignatureError(PackageError):
    """Signature malformed, not matching the content, or missing/untrusted when required."""

    code = ErrorCode.BAD_SIGNATURE


class DestinationExistsError(PackageError):
    """Unpack destination exists and is not empty (and overwrite was not asked)."""

    code = ErrorCode.DESTINATION_EXISTS


class BuildError(PackageError):
    """A source directory cannot be packaged."""

    code = ErrorCode.BUILD_FAILED


# ---------------------------------------------------------------------------------- keys
def sha256_hex(data: bytes) -> str:
    """Hex sha256 of ``data``."""
    return hashlib.sha256(data).hexdigest()


def generate_keypair() -> tuple[Ed25519PrivateKey, str]:
    """New ed25519 private key and its public key as base64 of the 32 raw bytes."""
    key = Ed25519PrivateKey.generate()
    return key, public_key_b64(key)


def private_key_to_pem(key: Ed25519PrivateKey) -> bytes:
    """Unencrypted PKCS#8 PEM of a private key (what `load_private_key` reads back)."""
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def load_private_key(source: Ed25519PrivateKey | bytes | str | os.PathLike[str]) -> Ed25519PrivateKey:
    """Ed25519 private key from a key object, PEM bytes/text, a PEM file path, or base64 raw seed."""
    if isinstance(source, Ed25519PrivateKey):
        return source
    if isinstance(source, os.PathLike):
        source = Path(source).read_bytes()
    if isinstance(source, str):
        try:
            is_file = "-----BEGIN" not in source and Path(source).is_file()
        except (OSError, ValueError):
            is_file = False
        source = Path(source).read_bytes() if is_file else source.encode()
    try:
        if b"-----BEGIN" in source:
            key = serialization.load_pem_private_key(source, password=None)
        else:
            key = Ed25519PrivateKey.from_private_bytes(base64.b64decode(source, validate=True))
    except (ValueError, TypeError, binascii.Error) as exc:
        raise ValueError(f"cannot load ed25519 private key: {exc}") from None
    if not isinstance(key, Ed25519PrivateKey):
        raise ValueError(f"not an ed25519 private key: {type(key).__name__}")
    return key


def load_public_key(source: Ed25519PublicKey | Ed25519PrivateKey | str | bytes) -> Ed25519PublicKey:
    """Ed25519 public key from a key object or base64 of the 32 raw bytes; ValueError otherwise."""
    if isinstance(source, Ed25519PublicKey):
        return source
    if isinstance(source, Ed25519PrivateKey):
        return source.public_key()
    try:
        raw = base64.b64decode(source, validate=True)
        return Ed25519PublicKey.from_public_bytes(raw)
    except (ValueError, TypeError, binascii.Error) as exc:
        raise ValueError(f"invalid ed25519 public key: {exc}") from None


def _raw_public(key: Ed25519PublicKey) -> bytes:
    return key.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)


def public_key_b64(key: Ed25519PublicKey | Ed25519PrivateKey | str | bytes) -> str:
    """Canonical base64 (raw 32 bytes) serialisation of a public key."""
    return base64.b64encode(_raw_public(load_public_key(key))).decode()


def public_key_id(key: Ed25519PublicKey | Ed25519PrivateKey | str | bytes) -> str:
    """Short stable id of a public key: first 16 hex digits of sha256 of its raw bytes."""
    return sha256_hex(_raw_public(load_public_key(key)))[:16]


# ---------------------------------------------------------------------------------- model
class SignatureStatus(str, Enum):
    """Outcome of signature checking (a bad signature is never a status: it raises)."""

    UNSIGNED = "unsigned"
    UNTRUSTED = "untrusted"  # valid signature, key not among trusted_keys (or none given)
    TRUSTED = "trusted"  # valid signature by a trusted key


@dataclass(frozen=True)
class PackageFile:
    """One file of a package (``SIGNATURE`` is not listed)."""

    path: str
    size: int
    sha256: str


@dataclass(frozen=True)
class Package:
    """What `read_package` learned about an archive, without writing anything."""

    manifest: Manifest
    files: tuple[PackageFile, ...]
    sha256: str  # of the archive bytes
    size: int  # archive bytes
    content_digest: str  # canonical digest the signature covers
    signature: SignatureStatus = SignatureStatus.UNSIGNED
    key_id: str | None = None
    public_key: str | None = None  # base64 raw, of the signer
    manifest_path: str = "manifest.yaml"

    @property
    def signed(self) -> bool:
        return self.signature is not SignatureStatus.UNSIGNED

    @property
    def trusted(self) -> bool:
        return self.signature is SignatureStatus.TRUSTED

    @property
    def total_size(self) -> int:
        return sum(f.size for f in self.files)

    @property
    def paths(self) -> list[str]:
        return [f.path for f in self.files]


@dataclass(frozen=True)
class Limits:
    """Resource limits applied while reading an archive."""

    max_size: int = DEFAULT_MAX_SIZE
    max_total: int = DEFAULT_MAX_TOTAL
    max_file: int = DEFAULT_MAX_FILE
    max_files: int = DEFAULT_MAX_FILES


# ---------------------------------------------------------------------------------- digest / signature
def content_digest(files: Mapping[str, bytes]) -> str:
    """Canonical hex digest of a package's files (``SIGNATURE`` excluded), see module doc."""
    h = hashlib.sha256(_CONTENT_PREFIX)
    for path in sorted(files):
        if path == SIGNATURE_NAME:
            continue
        data = files[path]
        h.update(f"{path}\t{len(data)}\t{sha256_hex(data)}\n".encode())
    return h.hexdigest()


def _sign(digest: str, key: Ed25519PrivateKey) -> bytes:
    pub = public_key_b64(key)
    doc = {
        "scheme": SIGNATURE_SCHEME,
        "key_id": public_key_id(pub),
        "public_key": pub,
        "content_digest": digest,
        "signature": base64.b64encode(key.sign(_SIGN_PREFIX + digest.encode())).decode(),
    }
    return (json.dumps(doc, sort_keys=True, indent=1) + "\n").encode()


TrustedKeys = Mapping[str, object] | Iterable[object] | None  # key objects, PEM or raw (by name or not)


def _trusted_raw(trusted_keys: TrustedKeys) -> set[bytes] | None:
    if trusted_keys is None:
        return None
    values = trusted_keys.values() if isinstance(trusted_keys, Mapping) else trusted_keys
    out = set()
    for value in values:
        out.add(_raw_public(load_public_key(value)))  # type: ignore[arg-type]
    return out


def _verify_signature(blob: bytes, digest: str) -> tuple[str, str]:
    """Check a SIGNATURE document against ``digest``; return (key_id, public_key_b64)."""
    try:
        doc = json.loads(blob.decode("utf-8"))
        if not isinstance(doc, dict):
            raise ValueError("not an object")
        scheme, pub, sig, signed_digest = (doc["scheme"], doc["public_key"], doc["signature"],
                                           doc["content_digest"])
        if not all(isinstance(v, str) for v in (scheme, pub, sig, signed_digest)):
            raise ValueError("fields must be strings")
        key = load_public_key(pub)
        raw_sig = base64.b64decode(sig, validate=True)
    except (ValueError, KeyError, UnicodeDecodeError, binascii.Error) as exc:
        raise SignatureError(f"malformed {SIGNATURE_NAME}: {exc}") from None
    if scheme != SIGNATURE_SCHEME:
        raise SignatureError(f"unsupported signature scheme {scheme!r}")
    if doc.get("key_id") not in (None, public_key_id(key)):
        raise SignatureError("signature key_id does not match its public key")
    if signed_digest != digest:
        raise SignatureError("package content does not match its signature (tampered?)")
    try:
        key.verify(raw_sig, _SIGN_PREFIX + digest.encode())
    except InvalidSignature:
        raise SignatureError("signature verification failed (tampered or wrong key)") from None
    return public_key_id(key), public_key_b64(key)


# ---------------------------------------------------------------------------------- reading
def _check_path(name: str) -> str:
    if not name or "\0" in name or "\\" in name:
        raise UnsafePathError(f"unsafe entry name {name!r}")
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        raise UnsafePathError(f"entry name is not valid UTF-8: {name!r}") from None
    if name.startswith("/") or (len(name) > 1 and name[1] == ":"):
        raise UnsafePathError(f"absolute path in archive: {name!r}")
    parts = PurePosixPath(name).parts
    if ".." in parts:
        raise UnsafePathError(f"path traversal ('..') in archive: {name!r}")
    norm = "/".join(p for p in name.split("/") if p not in ("", "."))
    if not norm or len(norm) > _MAX_PATH:
        raise UnsafePathError(f"invalid entry name {name!r}")
    return norm


def _entry_kind(member: tarfile.TarInfo) -> str:
    if member.issym():
        return "symlink"
    if member.islnk():
        return "hard link"
    if member.ischr() or member.isblk():
        return "device"
    if member.isfifo():
        return "fifo"
    return f"type {member.type!r}"


def _gunzip(data: bytes, cap: int) -> bytes:
    """Decompress a single gzip stream, refusing output beyond ``cap`` bytes (gzip bombs)."""
    dec = zlib.decompressobj(wbits=31)
    try:
        out = dec.decompress(data, cap + 1)
    except zlib.error as exc:
        raise CorruptArchiveError(f"corrupt archive: not a valid gzip stream ({exc})") from None
    if len(out) > cap or dec.unconsumed_tail:
        raise PackageTooLargeError(f"archive expands beyond {cap} bytes")
    if not dec.eof:
        raise CorruptArchiveError("corrupt archive: truncated gzip stream")
    return out


def _read_members(data: bytes, limits: Limits) -> dict[str, bytes]:
    """Read every regular file of the archive into memory, enforcing all limits and path rules."""
    files: dict[str, bytes] = {}
    dirs: set[str] = set()
    total = 0
    count = 0
    raw = _gunzip(data, limits.max_total + _HEADER_ALLOWANCE * (limits.max_files + 2) + 65536)
    try:
        with tarfile.open(fileobj=io.BytesIO(raw), mode="r:") as tar:
            for member in tar:
                count += 1
                if count > limits.max_files:
                    raise TooManyFilesError(f"archive has more than {limits.max_files} entries")
                name = _check_path(member.name)
                if member.isdir():
                    dirs.add(name)
                    continue
                if not member.isreg():
                    raise UnsafeEntryError(f"{_entry_kind(member)} entries are not allowed: {name!r}")
                if name in files:
                    raise UnsafePathError(f"duplicate entry in archive: {name!r}")
                if member.size > limits.max_file:
                    raise PackageTooLargeError(
                        f"file {name!r} is {member.size} bytes, limit {limits.max_file}")
                total += member.size
                if total > limits.max_total:
                    raise PackageTooLargeError(f"unpacked size exceeds limit of {limits.max_total} bytes")
                fobj = tar.extractfile(member)
                content = fobj.read() if fobj is not None else b""
                if len(content) != member.size:
                    raise CorruptArchiveError(f"truncated entry {name!r}")
                files[name] = content
    except PackageError:
        raise
    except (tarfile.TarError, EOFError, zlib.error, OSError, ValueError, UnicodeError,
            OverflowError) as exc:
        raise CorruptArchiveError(f"corrupt archive: {exc or type(exc).__name__}") from None
    _check_conflicts(files, dirs)
    return files


def _check_conflicts(files: Mapping[str, bytes], dirs: set[str]) -> None:
    parents = set(dirs)
    for path in files:
        parts = path.split("/")
        parents.update("/".join(parts[:i]) for i in range(1, len(parts)))
    clash = sorted(parents & set(files))
    if clash:
        raise UnsafePathError(f"entry {clash[0]!r} is both a file and a directory")


def _package_from_files(data: bytes, files: dict[str, bytes], *, trusted_keys: TrustedKeys,
                        require_signature: bool) -> Package:
    present = [n for n in MANIFEST_NAMES if n in files]
    if not present:
        raise MissingManifestError("archive has no manifest.yaml (or manifest.json) at its root")
    if len(present) > 1:
        raise InvalidManifestError("archive has both manifest.yaml and manifest.json")
    manifest_path = present[0]
    try:
        manifest = parse_manifest(files[manifest_path], manifest_format(manifest_path))
    except ManifestError as exc:
        raise InvalidManifestError(str(exc)) from None
    for field_name in ("entry_point", "cloud_entry_point"):
        ep = getattr(manifest, field_name)
        if ep is not None and not any(p in files for p in entry_point_module_paths(ep)):
            a, b = entry_point_module_paths(ep)
            raise EntryPointError(f"{field_name} {ep!r}: module file {a} (or {b}) is not in the archive")

    digest = content_digest(files)
    status, key_id, pub = SignatureStatus.UNSIGNED, None, None
    if SIGNATURE_NAME in files:
        if len(files[SIGNATURE_NAME]) > _MAX_SIGNATURE_SIZE:
            raise SignatureError(f"{SIGNATURE_NAME} is too large")
        key_id, pub = _verify_signature(files[SIGNATURE_NAME], digest)
        trusted = _trusted_raw(trusted_keys)
        if trusted is not None and base64.b64decode(pub) in trusted:
            status = SignatureStatus.TRUSTED
        else:
            status = SignatureStatus.UNTRUSTED
    if require_signature:
        if status is SignatureStatus.UNSIGNED:
            raise SignatureError("package is not signed and a signature is required")
        if trusted_keys is not None and status is not SignatureStatus.TRUSTED:
            raise SignatureError(f"package is signed by untrusted key {key_id}")

    listing = tuple(PackageFile(p, len(files[p]), sha256_hex(files[p]))
                    for p in sorted(files) if p != SIGNATURE_NAME)
    return Package(manifest=manifest, files=listing, sha256=sha256_hex(data), size=len(data),
                   content_digest=digest, signature=status, key_id=key_id, public_key=pub,
                   manifest_path=manifest_path)


def _load(data: bytes, *, max_size: int, max_total: int, max_file: int, max_files: int,
          trusted_keys: TrustedKeys, require_signature: bool) -> tuple[Package, dict[str, bytes]]:
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise TypeError("package data must be bytes")
    data = bytes(data)
    if len(data) > max_size:
        raise PackageTooLargeError(f"archive is {len(data)} bytes, limit {max_size}")
    files = _read_members(data, Limits(max_size, max_total, max_file, max_files))
    pkg = _package_from_files(data, files, trusted_keys=trusted_keys,
                              require_signature=require_signature)
    return pkg, files


def read_package(data: bytes, *, max_size: int = DEFAULT_MAX_SIZE, max_total: int = DEFAULT_MAX_TOTAL,
                 max_file: int = DEFAULT_MAX_FILE, max_files: int = DEFAULT_MAX_FILES,
                 trusted_keys: Mapping[str, object] | Iterable[object] | None = None,
                 require_signature: bool = False) -> Package:
    """Validate an archive in memory and describe it; never writes to disk.

    Raises a `PackageError` subclass for any refusal. ``trusted_keys`` is an iterable of public
    keys (base64 raw or key objects) or a mapping whose values are such keys. A signature that
    does not verify is always refused. With ``require_signature`` the package must be signed, and
    if ``trusted_keys`` is given, by one of them (``trusted_keys=None`` accepts any valid signer).
    """
    pkg, _ = _load(data, max_size=max_size, max_total=max_total, max_file=max_file,
                   max_files=max_files, trusted_keys=trusted_keys, require_signature=require_signature)
    return pkg


def unpack_package(data: bytes, dest_dir: str | os.PathLike[str], *, max_size: int = DEFAULT_MAX_SIZE,
                   max_total: int = DEFAULT_MAX_TOTAL, max_file: int = DEFAULT_MAX_FILE,
                   max_files: int = DEFAULT_MAX_FILES,
                   trusted_keys: Mapping[str, object] | Iterable[object] | None = None,
                   require_signature: bool = False, overwrite: bool = False) -> Package:
    """Validate (as `read_package`) then extract into ``dest_dir``; all or nothing.

    Files are written (mode 0644, ``SIGNATURE`` included) into a temporary sibling directory that
    is renamed to ``dest_dir`` at the end, so a refusal writes nothing. ``dest_dir`` must not
    exist or be empty, unless ``overwrite`` (then the old directory is replaced).
    """
    pkg, files = _load(data, max_size=max_size, max_total=max_total, max_file=max_file,
                       max_files=max_files, trusted_keys=trusted_keys,
                       require_signature=require_signature)
    dest = Path(dest_dir).absolute()
    if dest.exists() and not overwrite and (not dest.is_dir() or any(dest.iterdir())):
        raise DestinationExistsError(f"destination {dest} exists and is not empty")
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{dest.name}.", suffix=".tmp", dir=dest.parent))
    try:
        for path in sorted(files):
            target = tmp.joinpath(*path.split("/"))
            target.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(target, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0),
                         0o644)
            with os.fdopen(fd, "wb") as fh:
                fh.write(files[path])
        os.chmod(tmp, 0o755)
        old = None
        if dest.exists():
            if dest.is_dir() and not any(dest.iterdir()):
                dest.rmdir()
            else:
                old = dest.with_name(f".{dest.name}.old-{os.getpid()}-{id(tmp)}")
                os.rename(dest, old)
        os.rename(tmp, dest)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True) if old.is_dir() else old.unlink()
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return pkg


# ---------------------------------------------------------------------------------- building
def _collect_sources(src: Path) -> dict[str, bytes]:
    files: dict[str, bytes] = {}
    for root, dirnames, filenames in os.walk(src, followlinks=False):
        rootp = Path(root)
        for d in list(dirnames):
            if d in _SKIP_DIRS or d.startswith("."):
                dirnames.remove(d)
            elif (rootp / d).is_symlink():
                raise BuildError(f"symlinks cannot be packaged: {rootp / d}")
        for name in filenames:
            full = rootp / name
            if name.startswith(".") or name.endswith(_SKIP_SUFFIXES) or name == SIGNATURE_NAME:
                continue
            rel = full.relative_to(src).as_posix()
            if rel in MANIFEST_NAMES:
                continue
            st = full.lstat()
            if not stat.S_ISREG(st.st_mode):
                raise BuildError(f"only regular files can be packaged: {full}")
            files[_check_path(rel)] = full.read_bytes()
    return files


def _tar_bytes(entries: list[tuple[str, bytes]]) -> bytes:
    raw = io.BytesIO()
    with tarfile.open(fileobj=raw, mode="w", format=tarfile.PAX_FORMAT) as tar:
        for path, content in entries:
            info = tarfile.TarInfo(path)
            info.size = len(content)
            info.mtime = FIXED_MTIME
            info.mode = 0o644
            info.uid = info.gid = 0
            info.uname = info.gname = ""
            tar.addfile(info, io.BytesIO(content))
    out = io.BytesIO()
    with gzip.GzipFile(filename="", mode="wb", fileobj=out, compresslevel=9, mtime=0) as gz:
        gz.write(raw.getvalue())
    return out.getvalue()


def build_package_bytes(src_dir: str | os.PathLike[str],
                        signing_key: Ed25519PrivateKey | bytes | str | os.PathLike[str] | None = None) -> bytes:
    """Archive bytes of a RApp source directory (see module doc); `PackageError` if invalid.

    The source must hold ``manifest.yaml`` or ``manifest.json``; hidden files, ``__pycache__``,
    ``*.pyc`` and ``*.rapp`` are skipped; symlinks are refused. The result is re-read with
    `read_package` so an archive that would be refused is never produced.
    """
    src = Path(src_dir)
    if not src.is_dir():
        raise BuildError(f"source directory {src} does not exist")
    try:
        manifest = load_manifest(src)
    except ManifestError as exc:
        raise InvalidManifestError(str(exc)) from None
    files = _collect_sources(src)
    files["manifest.yaml"] = manifest.to_yaml().encode()
    entries = [("manifest.yaml", files["manifest.yaml"])]
    entries += [(p, files[p]) for p in sorted(files) if p != "manifest.yaml"]
    if signing_key is not None:
        key = load_private_key(signing_key)
        entries.append((SIGNATURE_NAME, _sign(content_digest(files), key)))
    data = _tar_bytes(entries)
    total = sum(len(c) for _, c in entries)
    read_package(data, max_size=max(DEFAULT_MAX_SIZE, len(data)),
                 max_total=max(DEFAULT_MAX_TOTAL, total),
                 max_file=max([DEFAULT_MAX_FILE] + [len(c) for _, c in entries]),
                 max_files=max(DEFAULT_MAX_FILES, len(entries)))
    return data


def package_filename(manifest: Manifest) -> str:
    """Conventional file name ``<name>-<version>.rapp``."""
    return f"{manifest.name}-{manifest.version}{PACKAGE_SUFFIX}"


def build_package(src_dir: str | os.PathLike[str], out_path: str | os.PathLike[str] | None = None,
                  signing_key: Ed25519PrivateKey | bytes | str | os.PathLike[str] | None = None) -> Path:
    """Build ``src_dir`` into a ``.rapp`` file and return its path.

    ``out_path`` may be a file path, an existing directory (file named `package_filename` inside)
    or None (that name in the current directory). The file is written atomically.
    """
    data = build_package_bytes(src_dir, signing_key)
    if out_path is None or Path(out_path).is_dir():
        manifest = load_manifest(Path(src_dir))
        out = Path(out_path or ".") / package_filename(manifest)
    else:
        out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", dir=out.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, out)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return out


__all__ = [
    "PackageError", "CorruptArchiveError", "PackageTooLargeError", "TooManyFilesError",
    "UnsafePathError", "UnsafeEntryError", "MissingManifestError", "InvalidManifestError",
    "EntryPointError", "SignatureError", "DestinationExistsError", "BuildError",
    "Package", "PackageFile", "SignatureStatus", "Limits",
    "sha256_hex", "content_digest", "generate_keypair", "private_key_to_pem", "load_private_key",
    "load_public_key", "public_key_b64", "public_key_id",
    "read_package", "unpack_package", "build_package", "build_package_bytes", "package_filename",
    "SIGNATURE_NAME", "SIGNATURE_SCHEME", "PACKAGE_SUFFIX",
]
