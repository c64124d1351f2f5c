"""Nothing lost: inputs are never modified, a full disk or a read-only folder gives a clear
error and leaves no output that looks complete."""

from __future__ import annotations

import errno
import hashlib
import pathlib
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pytest

from fuse4d import OutputWriteError, Sequence
from fuse4d.cli import EXIT_USAGE, main
from fuse4d.flow import write_flo
from fuse4d.io import write_frame_folder, write_npz, write_ply


@pytest.fixture
def inputs(tmp_path, small_sequence: Sequence) -> Path:
    """Every input kind in one folder (the folder is hashed before and after commands)."""
    root = tmp_path / "inputs"
    root.mkdir()
    write_npz(small_sequence, root / "s.npz")
    write_frame_folder(small_sequence, root / "seq", depth_unit_mm=0.01)
    for k in range(2):
        image = (small_sequence.intensity[k] * 255).astype(np.uint8)
        assert cv2.imwrite(str(root / f"i{k}.png"), image)
    (root / "c.toml").write_text("[fusion]\nspatial_radius = 2\n")
    (root / "cache_in.toml").write_text(f"[flow]\ncache_dir = '{root / 'seq' / 'depth'}'\n")
    return root


def _hashes(root: Path) -> dict[str, tuple[str, int]]:
    out = {}
    for p in sorted(root.rglob("*")):
        st = p.lstat()
        digest = hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir"
        out[p.relative_to(root).as_posix()] = (digest, st.st_mode)
    return out


def _commands(i: Path, o: Path) -> list[list[str]]:
    npz, seq = str(i / "s.npz"), str(i / "seq")
    return [
        ["info", npz],
        ["info", seq, "--json"],
        ["export-ply", seq, "--frame", "1", "-o", str(o / "f.ply")],
        ["export-ply", npz, "-o", npz, "--force"],  # refused: onto the input
        ["run", npz, "-o", str(o / "r.npz"), "--window", "3", "--config", str(i / "c.toml")],
        ["run", npz, "-o", npz, "--force"],  # refused
        ["run", seq, "-o", str(o / "r"), "--window", "3"],
        ["run", seq, "-o", str(o / "r"), "--window", "3", "--force"],
        ["run", seq, "-o", str(i / "seq" / "inside"), "--window", "3"],  # refused
        ["run", seq, "-o", str(o / "r"), "--resume"],  # refused: output complete
        # refused: the flow cache wrote hash-named folders into the input
        ["run", seq, "-o", str(o / "r3"), "--flow-cache", str(i / "seq" / "depth")],
        ["run", seq, "-o", str(o / "r4"), "--config", str(i / "cache_in.toml")],  # the same
        ["baseline", "temporal-mean", npz, "-o", str(o / "b.npz")],
        ["baseline", "guided", npz, "-o", npz, "--force"],  # refused (it used to replace it)
        ["baseline", "guided", seq, "-o", str(i / "seq" / "depth"), "--force"],  # refused
        ["flow", str(i / "i0.png"), str(i / "i1.png"), "-o", str(o / "f.flo")],
        ["flow", str(i / "i0.png"), str(i / "i1.png"), "-o", str(i / "i1.png"), "--force"],
        ["metrics", str(o / "r.npz"), "--json"],
        ["info", str(i / "missing")],
    ]


def test_no_command_modifies_its_input(inputs, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    before = _hashes(inputs)
    codes = []
    for args in _commands(inputs, out):
        codes.append(main(args))
        assert _hashes(inputs) == before, f"fuse4d {' '.join(args)} modified its input"
    assert codes.count(0) >= 9, codes
    assert set(codes) <= {0, EXIT_USAGE}, codes  # no crash on any of them
    capsys.readouterr()


# ----------------------------------------------------------------------------- full disk
class _FullFile:
    """A file object that fails with ENOSPC once ``budget`` bytes have been written."""

    def __init__(self, handle, budget: list[int]):
        self._handle = handle
        self._budget = budget

    def write(self, data) -> int:
        n = len(data) if isinstance(data, str) else len(memoryview(data).cast("B"))
        if self._budget[0] < n:
            raise OSError(errno.ENOSPC, "No space left on device")
        self._budget[0] -= n
        return self._handle.write(data)

    def __getattr__(self, name):
        return getattr(self._handle, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._handle.close()


@pytest.fixture
def full_disk(monkeypatch, tmp_path):
    """Writes under ``tmp_path/out`` fail with ENOSPC after ``budget[0]`` bytes in all."""
    target = tmp_path / "out"
    target.mkdir()
    budget = [0]
    real_open = pathlib.Path.open

    def open_(self, mode="r", *args, **kwargs):
        handle = real_open(self, mode, *args, **kwargs)
        if any(c in mode for c in "wax") and target in Path(self).absolute().parents:
            return _FullFile(handle, budget)
        return handle

    monkeypatch.setattr(pathlib.Path, "open", open_)
    return target, budget


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*"))


@pytest.mark.parametrize("budget", [0, 1000, 20_000])
def test_full_disk_npz_gives_clear_error_and_no_file(full_disk, inputs, capsys, budget):
    out, left = full_disk
    left[0] = budget
    code = main(["baseline", "temporal-mean", str(inputs / "s.npz"), "-o", str(out / "b.npz")])
    assert code == EXIT_USAGE
    err = capsys.readouterr().err.strip()
    assert err.startswith("fuse4d: error: ")
    assert "No space left on device" in err
    assert "free some disk space" in err
    assert len(err.splitlines()) == 1
    assert _leftovers(out) == []  # no partial file, no temporary


@pytest.mark.parametrize("budget", [0, 100])
def test_full_disk_ply_and_flo_leave_nothing(full_disk, small_sequence, budget):
    out, left = full_disk
    left[0] = budget
    points = np.ones((50, 3), np.float32)
    with pytest.raises(OutputWriteError, match="No space left"):
        write_ply(points, out / "c.ply")
    with pytest.raises(OutputWriteError, match="No space left"):
        write_flo(np.zeros((40, 40, 2), np.float32), out / "f.flo")
    assert _leftovers(out) == []


def test_full_disk_folder_run_keeps_complete_frames_and_resumes(
    full_disk, inputs, tmp_path, capsys
):
    """A run that fills the disk stops with a clear error; its complete frames are kept in
    OUT.partial (not readable as a recording) and --resume finishes it once space is back."""
    out, left = full_disk
    left[0] = 2500  # a few frames' PNGs
    args = ["run", str(inputs / "seq"), "-o", str(out / "r"), "--window", "3"]
    assert main(args) == EXIT_USAGE
    assert "No space left on device" in capsys.readouterr().err
    assert not (out / "r").exists()
    partial = out / "r.partial"
    names = _leftovers(partial)
    assert not [n for n in names if Path(n).name.startswith(".")], names  # no temporaries
    assert "camera.json" not in names
    left[0] = 10**9
    assert main([*args, "--resume"]) == 0
    ref = tmp_path / "ref"
    assert main(["run", str(inputs / "seq"), "-o", str(ref), "--window", "3"]) == 0
    for sub in ("depth", "intensity"):
        for p in sorted((ref / sub).iterdir()):
            assert (out / "r" / sub / p.name).read_bytes() == p.read_bytes()


def test_read_only_output_folder_gives_clear_error(monkeypatch, inputs, tmp_path, capsys):
    """Root ignores permission bits, so the refusal of a read-only folder is simulated."""
    ro = tmp_path / "ro"
    ro.mkdir()
    real_mkstemp, real_mkdtemp = tempfile.mkstemp, tempfile.mkdtemp

    def refuse(real):
        def wrapper(*args, dir=None, **kwargs):
            if dir is not None and Path(dir).absolute() == ro:
                raise PermissionError(errno.EACCES, "Permission denied", str(dir))
            return real(*args, dir=dir, **kwargs)

        return wrapper

    monkeypatch.setattr(tempfile, "mkstemp", refuse(real_mkstemp))
    monkeypatch.setattr(tempfile, "mkdtemp", refuse(real_mkdtemp))
    real_mkdir = pathlib.Path.mkdir

    def mkdir(self, *args, **kwargs):
        if Path(self).absolute().parent == ro:
            raise PermissionError(errno.EACCES, "Permission denied", str(self))
        return real_mkdir(self, *args, **kwargs)

    monkeypatch.setattr(pathlib.Path, "mkdir", mkdir)
    real_touch = pathlib.Path.touch

    def touch(self, *args, **kwargs):  # how the atomic writers create their temporary files
        if Path(self).absolute().parent == ro:
            raise PermissionError(errno.EACCES, "Permission denied", str(self))
        return real_touch(self, *args, **kwargs)

    monkeypatch.setattr(pathlib.Path, "touch", touch)
    for args in (
        ["run", str(inputs / "s.npz"), "-o", str(ro / "r.npz"), "--window", "3"],
        ["run", str(inputs / "seq"), "-o", str(ro / "r"), "--window", "3"],
        ["export-ply", str(inputs / "s.npz"), "-o", str(ro / "c.ply")],
    ):
        assert main(args) == EXIT_USAGE, args
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1, err
        assert "Permission denied" in err
        assert "not writable" in err
    assert _leftovers(ro) == []


@pytest.mark.parametrize("directory", [False, True])
def test_a_folder_that_takes_no_files_names_the_output(tmp_path, monkeypatch, directory):
    """A folder that exists but refuses new entries (``/proc``: ENOENT) is reported for the
    output the user named, not for fuse4d's temporary ``.NAME.tmp-XXXXXXXX``."""
    from fuse4d.io._atomic import atomic_dir, atomic_file

    def refuse(self, *args, **kwargs):
        raise FileNotFoundError(2, "No such file or directory", str(self))

    monkeypatch.setattr(Path, "mkdir" if directory else "touch", refuse)
    target = tmp_path / ("out" if directory else "c.ply")
    with (
        pytest.raises(OutputWriteError) as info,
        (atomic_dir if directory else atomic_file)(target),
    ):
        pass
    assert str(info.value) == f"{target}: cannot write the output (No such file or directory)"


def _ro_touch(monkeypatch, ro: Path) -> None:
    """New files in ``ro`` are refused as on a read-only mount (root ignores mode bits)."""
    real_touch = pathlib.Path.touch

    def touch(self, *args, **kwargs):
        if Path(self).absolute().parent == ro:
            raise OSError(errno.EROFS, "Read-only file system", str(self))
        return real_touch(self, *args, **kwargs)

    monkeypatch.setattr(pathlib.Path, "touch", touch)


def test_an_unwritable_second_output_is_refused_before_the_first_is_written(
    monkeypatch, inputs, tmp_path, capsys
):
    """`run -o y.npz --report RO/rep` wrote y.npz, then failed on the report folder (and a
    rerun was refused: 'exists'); every output's folder is now tried before the work."""
    ro, out = tmp_path / "ro", tmp_path / "out"
    ro.mkdir()
    out.mkdir()
    _ro_touch(monkeypatch, ro)
    args = ["run", str(inputs / "s.npz"), "-o", str(out / "y.npz"), "--window", "3"]
    assert main([*args, "--report", str(ro / "rep")]) == EXIT_USAGE
    err = capsys.readouterr().err.strip()
    assert err == (
        f"fuse4d: error: {ro / 'rep'}: cannot write the output (Read-only file system); the "
        "file system is read-only: choose another output path"
    )
    assert _leftovers(out) == []
    assert _leftovers(ro) == []


def _dead_pid() -> int:
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    return int(proc.stdout)


def test_temporaries_of_a_killed_run_are_removed_by_the_next_write(tmp_path, small_sequence):
    """SIGKILL (or a power cut) left hidden '.NAME.tmp-*' files and folders (81 MB each for
    a 200-frame .npz) that nothing ever removed; the next write of that output removes those
    of processes that no longer exist, and keeps a live writer's."""
    from fuse4d.io._atomic import _host_tag

    dead, host = _dead_pid(), _host_tag()
    stale_file = tmp_path / f".k.npz.tmp-{host}-{dead}-0123abcd"
    stale_file.write_bytes(b"x" * 100)
    live = tmp_path / f".k.npz.tmp-{host}-1-0123abcd"  # pid 1 is always alive
    live.write_bytes(b"x")
    stale_dir = tmp_path / f".r.tmp-{host}-{dead}-89abcdef"
    (stale_dir / "depth").mkdir(parents=True)
    other = tmp_path / f".other.npz.tmp-{host}-{dead}-0123abcd"  # another output's
    other.write_bytes(b"x")
    # another host's (a shared folder): its process is not one of ours to look up
    elsewhere = tmp_path / f".k.npz.tmp-{int(host, 16) ^ 1:08x}-{dead}-0123abcd"
    elsewhere.write_bytes(b"x")
    write_npz(small_sequence, tmp_path / "k.npz")
    write_frame_folder(small_sequence, tmp_path / "r", depth_unit_mm=0.01)
    assert not stale_file.exists()
    assert not stale_dir.exists()
    assert live.exists()
    assert other.exists()
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == sorted([live.name, other.name, elsewhere.name, "k.npz", "r"])


def test_an_old_copy_is_kept_while_the_output_is_missing(tmp_path, small_sequence):
    """A kill between the two renames of a --force replacement leaves the previous output
    only in '.NAME.old-*': it is not swept while NAME is missing."""
    from fuse4d.io._atomic import _host_tag

    old = tmp_path / f".r.old-{_host_tag()}-{_dead_pid()}-0123abcd"
    (old / "depth").mkdir(parents=True)
    write_npz(small_sequence, tmp_path / "r.npz")  # another output: nothing swept for r
    assert old.exists()
    write_frame_folder(
        small_sequence, tmp_path / "r", depth_unit_mm=0.01
    )  # r is written, its old copy kept
    assert old.exists()
    write_frame_folder(
        small_sequence, tmp_path / "r", depth_unit_mm=0.01, overwrite=True
    )  # r exists now
    assert not old.exists()


def test_interrupt_while_deleting_the_replaced_folder_finishes_the_deletion(
    tmp_path, small_sequence, monkeypatch
):
    """A Ctrl-C after `--force` had renamed the new folder into place, while the old one was
    being deleted, left the old copy hidden beside the output for good."""
    import shutil

    from fuse4d.io import _atomic

    out = tmp_path / "r"
    write_frame_folder(small_sequence, out, depth_unit_mm=0.01)
    real_rmtree = shutil.rmtree
    calls = []

    def interrupted_rmtree(path, *args, **kwargs):
        calls.append(Path(path).name)
        if len(calls) == 1:
            real_rmtree(Path(path) / "depth", *args, **kwargs)  # part of the work done
            raise KeyboardInterrupt
        return real_rmtree(path, *args, **kwargs)

    monkeypatch.setattr(_atomic.shutil, "rmtree", interrupted_rmtree)
    with pytest.raises(KeyboardInterrupt):
        write_frame_folder(small_sequence.frames(0, 2), out, depth_unit_mm=0.01, overwrite=True)
    assert calls[0].startswith(".r.old-")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r"]
    assert len(list((out / "depth").iterdir())) == 2  # the new output


def test_a_leftover_that_cannot_be_removed_does_not_stop_the_write(
    tmp_path, small_sequence, monkeypatch
):
    """Another user's leftover in a shared folder (EPERM on unlink) made the write fail,
    naming the temporary; the sweep is best effort."""
    from fuse4d.io._atomic import _host_tag

    stale = tmp_path / f".k.npz.tmp-{_host_tag()}-{_dead_pid()}-0123abcd"
    stale.write_bytes(b"x")
    real_unlink = pathlib.Path.unlink

    def unlink(self, *args, **kwargs):
        if Path(self) == stale:
            raise PermissionError(errno.EPERM, "Operation not permitted", str(self))
        return real_unlink(self, *args, **kwargs)

    monkeypatch.setattr(pathlib.Path, "unlink", unlink)
    write_npz(small_sequence, tmp_path / "k.npz")
    assert stale.exists()
    assert (tmp_path / "k.npz").is_file()


def test_writing_many_files_into_a_folder_does_not_sweep_per_file(
    tmp_path, small_sequence, monkeypatch
):
    """The sweep ran for every PNG a folder run wrote (a listing of the growing folder per
    file: 7 ms a frame after 4000 frames); it runs once per output."""
    from fuse4d.io import _atomic

    write_frame_folder(small_sequence, tmp_path / "s", depth_unit_mm=0.01)
    calls = []
    real = _atomic._sweep_dead_temporaries
    monkeypatch.setattr(_atomic, "_sweep_dead_temporaries", lambda d: calls.append(d) or real(d))
    args = [str(tmp_path / "s"), "-o", str(tmp_path / "r"), "--window", "3", "--no-summary"]
    assert main(["run", *args]) == 0
    pngs = 2 * small_sequence.num_frames  # depth and intensity (source, confidence: more)
    assert len({p.name for p in calls}) <= 3, calls  # the output, its .partial (and staging)
    assert len(calls) < pngs, calls


def test_resume_of_a_finished_run_in_a_read_only_folder_succeeds(
    monkeypatch, inputs, tmp_path, capsys
):
    """The up-front try of the output folder failed a --resume that writes nothing."""
    ro = tmp_path / "ro"
    ro.mkdir()
    args = ["run", str(inputs / "seq"), "-o", str(ro / "r"), "--window", "3", "--no-summary"]
    assert main(args) == 0
    _ro_touch(monkeypatch, ro)
    capsys.readouterr()
    assert main([*args, "--resume"]) == 0
    assert "already complete" in " ".join(capsys.readouterr().err.split())


def test_flow_vis_in_a_read_only_folder_fails_before_the_flo_is_written(
    monkeypatch, inputs, tmp_path, capsys
):
    ro, out = tmp_path / "ro", tmp_path / "out"
    ro.mkdir()
    out.mkdir()
    _ro_touch(monkeypatch, ro)
    args = ["flow", str(inputs / "i0.png"), str(inputs / "i1.png"), "-o", str(out / "f.flo")]
    assert main([*args, "--vis", str(ro / "v.png")]) == EXIT_USAGE
    assert "Read-only file system" in capsys.readouterr().err
    assert _leftovers(out) == []
