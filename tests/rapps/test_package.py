"""Package building, inspection, signatures and safe unpacking."""
from __future__ import annotations

import gzip
import io
import json
import os
import tarfile
from pathlib import Path

import pytest
from hypothesis import given, settings, strategies as st

from ontology.package import (
    BuildError, CorruptArchiveError, DestinationExistsError, EntryPointError, InvalidManifestError,
    MissingManifestError, PackageError, PackageTooLargeError, SignatureError, SignatureStatus,
    TooManyFilesError, UnsafeEntryError, UnsafePathError, build_package, build_package_bytes,
    content_digest, generate_keypair, load_private_key, private_key_to_pem, public_key_b64,
    public_key_id, read_package, sha256_hex, unpack_package,
)
from ontology.manifest import ManifestError
from tests.rapps.helpers import make_archive, make_src, valid_entries

EXAMPLE = Path(__file__).resolve().parents[2] / "rapps" / "examples" / "hello"


@pytest.fixture
def src(tmp_path):
    return make_src(tmp_path / "src")


@pytest.fixture(scope="module")
def keys():
    return generate_keypair(), generate_keypair()


def _members(data: bytes) -> dict[str, bytes]:
    with tarfile.open(fileobj=io.BytesIO(data), mode="r:gz") as tar:
        return {m.name: tar.extractfile(m).read() for m in tar if m.isreg()}


def _retar(files: dict[str, bytes]) -> bytes:
    return make_archive([(n, None, c) for n, c in files.items()])


# ---------------------------------------------------------------- round trip / determinism
def test_build_read_unpack_round_trip(src, tmp_path):
    (src / "__pycache__").mkdir()
    (src / "__pycache__" / "x.cpython-311.pyc").write_bytes(b"junk")
    (src / ".hidden").write_text("secret")
    out = build_package(src, tmp_path / "out")  # existing dir? no -> file path
    data = out.read_bytes()
    pkg = read_package(data)
    assert pkg.manifest.name == "demo"
    assert pkg.paths == ["data/words.txt", "demo/task.py", "manifest.yaml"]
    assert pkg.sha256 == sha256_hex(data) and pkg.size == len(data)
    assert pkg.signature is SignatureStatus.UNSIGNED and not pkg.signed
    dest = tmp_path / "unpacked"
    again = unpack_package(data, dest)
    assert again == pkg
    assert (dest / "demo" / "task.py").read_text().startswith("class DemoTask")
    assert (dest / "data" / "words.txt").read_text() == "wave\nhello\n"
    assert not (dest / "__pycache__").exists() and not (dest / ".hidden").exists()
    for f in pkg.files:
        assert sha256_hex((dest / f.path).read_bytes()) == f.sha256


def test_build_default_name_and_directory(src, tmp_path):
    outdir = tmp_path / "dist"
    outdir.mkdir()
    assert build_package(src, outdir) == outdir / "demo-1.0.0.rapp"
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        assert build_package(src).resolve() == (tmp_path / "demo-1.0.0.rapp").resolve()
    finally:
        os.chdir(cwd)


def test_build_is_deterministic(src, keys):
    (key, _), _ = keys
    a = build_package_bytes(src)
    os.utime(src / "demo" / "task.py", (1, 1))
    assert build_package_bytes(src) == a
    assert build_package_bytes(src, key) == build_package_bytes(src, key)


def test_archive_layout(src):
    with tarfile.open(fileobj=io.BytesIO(build_package_bytes(src)), mode="r:gz") as tar:
        members = tar.getmembers()
    assert members[0].name == "manifest.yaml"
    assert all(m.isreg() and m.mode == 0o644 and m.uid == 0 for m in members)


def test_example_hello_builds(tmp_path):
    pkg = read_package(build_package_bytes(EXAMPLE))
    assert pkg.manifest.entry_point == "hello.task:HelloTask"
    assert "hello/task.py" in pkg.paths


def test_build_refuses_bad_sources(tmp_path):
    with pytest.raises(BuildError):
        build_package_bytes(tmp_path / "missing")
    bad = make_src(tmp_path / "bad", version="one")
    with pytest.raises(InvalidManifestError, match="version"):
        build_package_bytes(bad)
    noentry = make_src(tmp_path / "noentry")
    (noentry / "demo" / "task.py").unlink()
    with pytest.raises(EntryPointError):
        build_package_bytes(noentry)
    link = make_src(tmp_path / "link")
    (link / "evil").symlink_to("/etc/passwd")
    with pytest.raises(BuildError, match="regular files"):
        build_package_bytes(link)


# ---------------------------------------------------------------- signatures
def test_signed_package_verifies(src, keys):
    (key, pub), _ = keys
    data = build_package_bytes(src, key)
    pkg = read_package(data, trusted_keys=[pub], require_signature=True)
    assert pkg.signature is SignatureStatus.TRUSTED and pkg.trusted
    assert pkg.key_id == public_key_id(pub) and pkg.public_key == pub
    assert "SIGNATURE" not in pkg.paths
    # no trust list: valid but untrusted; mapping form of trusted keys
    assert read_package(data).signature is SignatureStatus.UNTRUSTED
    assert read_package(data, trusted_keys={pkg.key_id: pub}).trusted
    # any valid signature when required without a trust list
    assert read_package(data, require_signature=True).signature is SignatureStatus.UNTRUSTED


def test_wrong_key_refused_when_required(src, keys):
    (key, _), (_, other_pub) = keys
    data = build_package_bytes(src, key)
    with pytest.raises(SignatureError, match="untrusted"):
        read_package(data, trusted_keys=[other_pub], require_signature=True)
    assert read_package(data, trusted_keys=[other_pub]).signature is SignatureStatus.UNTRUSTED


def test_unsigned_refused_when_required(src, keys):
    (_, pub), _ = keys
    with pytest.raises(SignatureError, match="not signed"):
        read_package(build_package_bytes(src), trusted_keys=[pub], require_signature=True)


def test_tampered_content_refused_always(src, keys):
    (key, pub), _ = keys
    files = _members(build_package_bytes(src, key))
    files["demo/task.py"] += b"import os; os.system('rm -rf /')\n"
    tampered = _retar(files)
    with pytest.raises(SignatureError, match="tampered"):
        read_package(tampered)
    with pytest.raises(SignatureError):
        unpack_package(tampered, src.parent / "x", trusted_keys=[pub], require_signature=True)
    assert not (src.parent / "x").exists()


def test_forged_signature_refused(src, keys):
    (key, _), (other, _) = keys
    files = _members(build_package_bytes(src, key))
    doc = json.loads(files["SIGNATURE"])
    doc["public_key"] = public_key_b64(other)  # claim another signer
    doc["key_id"] = public_key_id(other)
    files["SIGNATURE"] = json.dumps(doc).encode()
    with pytest.raises(SignatureError, match="verification failed"):
        read_package(_retar(files))
    files["SIGNATURE"] = b"not json"
    with pytest.raises(SignatureError, match="malformed"):
        read_package(_retar(files))


def test_key_helpers(tmp_path, keys):
    (key, pub), _ = keys
    pem = private_key_to_pem(key)
    (tmp_path / "k.pem").write_bytes(pem)
    for source in (key, pem, pem.decode(), tmp_path / "k.pem", str(tmp_path / "k.pem")):
        assert public_key_b64(load_private_key(source)) == pub
    assert len(public_key_id(pub)) == 16
    with pytest.raises(ValueError):
        load_private_key(b"garbage")
    assert content_digest({"b": b"1", "a": b"2"}) == content_digest({"a": b"2", "b": b"1", "SIGNATURE": b"x"})


# ---------------------------------------------------------------- hostile archives
@pytest.mark.parametrize("entries,error,text", [
    ([("../evil.py", None, b"x")], UnsafePathError, "traversal"),
    ([("demo/../../evil.py", None, b"x")], UnsafePathError, "traversal"),
    ([("/etc/evil", None, b"x")], UnsafePathError, "absolute"),
    ([("C:/evil", None, b"x")], UnsafePathError, "absolute"),
    ([("link", tarfile.SYMTYPE, b"/etc/passwd")], UnsafeEntryError, "symlink"),
    ([("hard", tarfile.LNKTYPE, b"manifest.yaml")], UnsafeEntryError, "hard link"),
    ([("dev", tarfile.CHRTYPE, b"")], UnsafeEntryError, "device"),
    ([("fifo", tarfile.FIFOTYPE, b"")], UnsafeEntryError, "fifo"),
    ([("demo/task.py", None, b"dup")], UnsafePathError, "duplicate"),
    ([("manifest.yaml/x", None, b"x")], UnsafePathError, "both a file and a directory"),
])
def test_hostile_entries_refused(tmp_path, entries, error, text):
    data = make_archive(valid_entries() + entries)
    with pytest.raises(error, match=text):
        read_package(data)
    dest = tmp_path / "dest"
    with pytest.raises(error):
        unpack_package(data, dest)
    assert not dest.exists()
    assert list(tmp_path.iterdir()) == []  # no temp dir left behind either


def test_corrupt_archives(src):
    good = build_package_bytes(src)
    for bad in (b"", b"not an archive", good[:len(good) // 2], good[:10] + b"\0" * 50 + good[60:],
                make_archive(valid_entries(), gz=False), gzip.compress(b"plain text, not tar")):
        with pytest.raises(CorruptArchiveError, match="corrupt"):
            read_package(bad)


def test_size_limits(src):
    data = build_package_bytes(src)
    with pytest.raises(PackageTooLargeError, match="archive is"):
        read_package(data, max_size=100)
    with pytest.raises(PackageTooLargeError, match="file"):
        read_package(data, max_file=10)
    with pytest.raises(PackageTooLargeError, match="unpacked size"):
        read_package(data, max_total=200)
    with pytest.raises(TooManyFilesError):
        read_package(data, max_files=2)


def test_gzip_bomb_refused():
    bomb = gzip.compress(b"\0" * (8 * 1024 * 1024))
    with pytest.raises(PackageTooLargeError, match="expands"):
        read_package(bomb, max_total=1024, max_files=2)


def test_missing_and_invalid_manifest():
    with pytest.raises(MissingManifestError, match="manifest"):
        read_package(make_archive([("demo/task.py", None, b"x")]))
    with pytest.raises(InvalidManifestError, match="robot_types") as exc:
        read_package(make_archive(valid_entries(robot_types=["toaster"])))
    assert isinstance(exc.value, ManifestError) and isinstance(exc.value, PackageError)
    with pytest.raises(InvalidManifestError, match="name"):
        read_package(make_archive(valid_entries(name="../../etc")))
    with pytest.raises(InvalidManifestError):
        read_package(make_archive([("manifest.yaml", None, b"[1, 2"), ("demo/task.py", None, b"")]))


def test_entry_points_must_exist():
    with pytest.raises(EntryPointError, match="demo/other.py"):
        read_package(make_archive(valid_entries(entry_point="demo.other:Task")))
    with pytest.raises(EntryPointError, match="cloud_entry_point"):
        read_package(make_archive(valid_entries(cloud_entry_point="cloud.agent:Cloud")))
    ok = valid_entries(entry_point="pkg:Task") + [("pkg/__init__.py", None, b"class Task: ...")]
    assert read_package(make_archive(ok)).manifest.entry_point == "pkg:Task"


def test_unpack_destination_rules(src, tmp_path):
    data = build_package_bytes(src)
    dest = tmp_path / "d"
    dest.mkdir()
    unpack_package(data, dest)  # empty directory is fine
    with pytest.raises(DestinationExistsError):
        unpack_package(data, dest)
    (dest / "stale.txt").write_text("old")
    unpack_package(data, dest, overwrite=True)
    assert not (dest / "stale.txt").exists() and (dest / "manifest.yaml").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d", "src"]


# ---------------------------------------------------------------- properties
@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=2048))
def test_random_bytes_only_raise_package_error(blob):
    with pytest.raises(PackageError):
        read_package(blob)
    with pytest.raises(PackageError):  # valid gzip, random tar stream
        read_package(gzip.compress(blob))


_GOOD_TAR = make_archive(valid_entries(), gz=False)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 3000), st.integers(0, 255)), min_size=1, max_size=4),
       st.booleans())
def test_mutated_archive_never_escapes(tmp_path_factory, edits, truncate):
    """Mutating the tar stream (then re-compressing, so gzip's CRC does not hide it)."""
    data = bytearray(_GOOD_TAR)
    for pos, value in edits:
        data[pos % len(data)] = value
    if truncate:
        data = data[:edits[0][0] % len(data)]
    dest = tmp_path_factory.mktemp("m") / "out"
    try:
        pkg = unpack_package(gzip.compress(bytes(data)), dest)
    except PackageError:
        assert not dest.exists()
    else:
        assert sorted(str(p.relative_to(dest)) for p in dest.rglob("*") if p.is_file()) == pkg.paths
