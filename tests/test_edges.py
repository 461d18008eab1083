"""What a new user trips on: picture formats by extension, progress bars only on a
terminal, quick benchmarks that leave the committed results alone, an unwritable
--out refused before any work, and docs whose links resolve."""

from __future__ import annotations

import io
import os
import re
import sys
from pathlib import Path

import pytest

import jackbox
from jackbox import bench, progress

from .conftest import run_cli

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def saved_run(tmp_path_factory):
    path = tmp_path_factory.mktemp("saved") / "trajectory.npz"
    jackbox.simulate("drop", t_end=0.05).save(path)
    return path


@pytest.mark.parametrize("ext, magic", [("png", b"\x89PNG\r\n\x1a\n"), ("pdf", b"%PDF-"), ("svg", b"<?xml")])
def test_plot_writes_the_format_its_extension_names(saved_run, tmp_path, capsys, ext, magic):
    out = tmp_path / f"x.{ext}"
    status, _, err = run_cli(capsys, "plot", str(saved_run), "--out", str(out), "-q")
    assert status == 0, err
    assert out.read_bytes().startswith(magic)


def test_plot_refuses_a_format_it_cannot_write_before_any_work(saved_run, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(jackbox.Trajectory, "load", _no_work)
    status, out, err = run_cli(capsys, "plot", str(saved_run), "--out", str(tmp_path / "x.jpg"))
    assert status == 2 and out == ""
    assert err.strip().splitlines() == [
        f"jackbox: error: {tmp_path / 'x.jpg'}: a picture is written as .png, .pdf, .svg, not .jpg"]
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("command", [["run", "drop", "--no-plots"], ["ensemble", "drop", "--n", "2"],
                                     ["chaos", "drop", "--n", "2"],
                                     ["compare", "drop", "--restitution", "1.0", "0.6"]])
def test_an_out_that_cannot_be_written_is_refused_before_any_work(tmp_path, capsys, monkeypatch, command):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    monkeypatch.setattr(jackbox.loader, "kernel_for", _no_work)
    status, out, err = run_cli(capsys, *command, "--t-end", "0.05", "--out", str(blocker / "out"))
    assert status == 2, err
    (line,) = err.strip().splitlines()
    assert line == f"jackbox: error: --out {blocker / 'out'}: {blocker} is a file, not a folder"


@pytest.mark.parametrize("flags", [[], ["--quick"], ["--compile"]], ids=["full", "quick", "compile"])
def test_a_bench_out_that_cannot_be_written_is_refused_before_measuring(tmp_path, capsys, monkeypatch, flags):
    """(it was found when the figures were written, after minutes of measuring)"""
    import jackbox.bench
    import jackbox.compilebench

    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    monkeypatch.setattr(jackbox.bench, "bench_scene", _no_work)
    monkeypatch.setattr(jackbox.compilebench, "main", _no_work)
    status, out, err = run_cli(capsys, "bench", *flags, "--out", str(blocker / "out"))
    assert status == 2, err
    (line,) = err.strip().splitlines()
    assert line == f"jackbox: error: --out {blocker / 'out'}: {blocker} is a file, not a folder"


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux's /proc")
def test_an_out_where_nothing_can_be_made_is_refused_even_for_root(capsys, monkeypatch):
    """/proc: its permission bits let root write, yet no file can be made there."""
    monkeypatch.setattr(jackbox.loader, "kernel_for", _no_work)
    status, out, err = run_cli(capsys, "run", "drop", "--no-plots", "--t-end", "0.05", "--out", "/proc/jackbox/out")
    assert status == 2 and out == ""
    (line,) = err.strip().splitlines()
    assert line.startswith("jackbox: error: --out /proc/jackbox/out: /proc cannot be written")


def test_progress_bars_only_on_a_terminal_unless_asked(monkeypatch):
    monkeypatch.delenv("JACKBOX_PROGRESS", raising=False)
    monkeypatch.setattr(sys, "stderr", io.StringIO())          # a log file, not a terminal
    assert not progress.wanted(True)
    assert isinstance(progress.progress_bar(10, True, "step"), progress._Off)

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    monkeypatch.setattr(sys, "stderr", Terminal())
    assert progress.wanted(True) and not progress.wanted(False)
    monkeypatch.setenv("JACKBOX_PROGRESS", "0")
    assert not progress.wanted(True)
    monkeypatch.setattr(sys, "stderr", io.StringIO())
    monkeypatch.setenv("JACKBOX_PROGRESS", "1")
    assert progress.wanted(True)
    bar = progress.progress_bar(10, True, "step")
    assert not isinstance(bar, progress._Off)
    bar.close()


def test_a_quick_benchmark_leaves_the_committed_results_alone():
    assert bench.default_out(quick=True) == Path("jackbox-bench-quick")
    assert bench.default_out(quick=False) == ROOT / "benchmarks" / "results"


def test_every_link_in_the_docs_resolves():
    link = re.compile(r"\]\(([^)\s]+)\)")
    docs = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")),
            *sorted((ROOT / "benchmarks" / "results").glob("*.md"))]
    broken = []
    for doc in docs:
        for target in link.findall(doc.read_text(encoding="utf-8")):
            if re.match(r"^[a-z]+://|^mailto:", target):
                continue                      # no network here: outside links are not checked
            path = target.split("#", 1)[0]
            if path and not (doc.parent / path).exists():
                broken.append(f"{doc.relative_to(ROOT)}: {target}")
    assert broken == []


def _no_work(*args, **kwargs):
    raise AssertionError("a refused command must not start its work")


def test_sigterm_while_writing_leaves_no_temporary_file(tmp_path, capsys, monkeypatch):
    import signal

    import numpy as np

    def killed_while_writing(fh, **arrays):
        fh.write(b"half a file")
        os.kill(os.getpid(), signal.SIGTERM)       # the handler raises here, mid-write

    monkeypatch.setattr(np, "savez_compressed", killed_while_writing)
    monkeypatch.setattr(np, "savez", killed_while_writing)
    out = tmp_path / "out"
    out.mkdir()
    (out / "trajectory.npz").write_bytes(b"an older run")
    before = signal.getsignal(signal.SIGTERM)
    status, _, err = run_cli(capsys, "run", "drop", "--t-end", "0.05", "--out", str(out), "--no-plots", "-q")
    assert status == 143 and "terminated" in err
    assert sorted(p.name for p in out.iterdir()) == ["trajectory.npz"]     # no temporary file
    assert (out / "trajectory.npz").read_bytes() == b"an older run"        # nothing lost
    assert signal.getsignal(signal.SIGTERM) == before                   # the handler was put back


def test_a_temporary_file_left_by_a_killed_writer_is_removed_by_the_next_write(tmp_path):
    import subprocess

    from jackbox.fileio import TMP_SUFFIX, write_atomic

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True, check=True)
    stale = tmp_path / f".trajectory.npz.{int(dead.stdout)}.abc123{TMP_SUFFIX}"
    stale.write_bytes(b"x" * 1000)
    mine = tmp_path / f".other.npz.{os.getpid()}.def456{TMP_SUFFIX}"        # a live writer's: kept
    mine.write_bytes(b"y")
    write_atomic(tmp_path / "timeseries.png", b"png")
    assert not stale.exists() and mine.exists()


def test_large_trajectories_are_saved_uncompressed_small_ones_compressed(tmp_path):
    import zipfile

    from jackbox import trajectory

    traj = jackbox.simulate("drop", t_end=0.05)
    small = traj.save(tmp_path / "small.npz")
    with zipfile.ZipFile(small) as z:
        assert {i.compress_type for i in z.infolist()} == {zipfile.ZIP_DEFLATED}
    big = traj.save(tmp_path / "big.npz", compress=False)
    with zipfile.ZipFile(big) as z:
        assert {i.compress_type for i in z.infolist()} == {zipfile.ZIP_STORED}
    assert trajectory.COMPRESS_BELOW <= 16 << 20      # a 1e6-step run (112 MB) is stored
    np_equal = jackbox.Trajectory.load(big)
    assert (np_equal.q == traj.q).all()


def test_a_runs_files_carry_one_run_id_and_a_folder_never_mixes_two_runs(tmp_path, capsys):
    out = tmp_path / "out"
    status, _, err = run_cli(capsys, "run", "drop", "--t-end", "0.05", "--out", str(out), "-q")
    assert status == 0, err
    run_id = jackbox.Trajectory.load(out / "trajectory.npz").meta["run_id"]
    assert re.fullmatch(r"[0-9a-f]{16}", run_id)
    assert f"tEXtTitle\x00jackbox run {run_id}".encode() in (out / "timeseries.png").read_bytes()
    assert f'<meta name="jackbox-run" content="{run_id}">' in (out / "animation.html").read_text()
    # a second run without pictures: the first run's pictures do not stay beside its trajectory
    status, stdout, _ = run_cli(capsys, "run", "drop", "--t-end", "0.05", "--out", str(out), "--no-plots")
    assert status == 0
    assert sorted(p.name for p in out.iterdir()) == ["trajectory.npz"]
    assert jackbox.Trajectory.load(out / "trajectory.npz").meta["run_id"] != run_id
    assert f"removed    {out / 'timeseries.png'} (an older run's)" in stdout
