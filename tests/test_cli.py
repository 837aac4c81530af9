"""The console script: commands run, bad names give a clear error and exit code 2."""

import subprocess

from quick import QUICK_ICP

from scapo.cli.main import main


def test_list_and_doctor(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    assert "laptop" in out and "icp" in out
    assert main(["doctor"]) == 0
    assert "render device" in capsys.readouterr().out


def test_unknown_category_is_a_clear_error(capsys):
    # in this process (the installed entry point's exit codes and messages: tests/test_user_facing.py)
    assert main(["generate", "--category", "teapot", "--instances", "2", "--views", "2", "--out", "/tmp/never"]) == 2
    assert "unknown category 'teapot'; known: basket, drawer, eyeglasses" in capsys.readouterr().err


def test_generate_predict_evaluate_round_trip(tmp_path, capsys):
    d = tmp_path / "ds"
    assert main(["generate", "--category", "oven", "--instances", "3", "--views", "3", "--out", str(d),
                 "--no-progress"]) == 0
    assert main(["predict", "--method", "icp", "--data", str(d), "--out", str(tmp_path / "p.npz"), *QUICK_ICP]) == 0
    assert main(["evaluate", "--data", str(d), "--pred", str(tmp_path / "p.npz"), "--out", str(tmp_path / "t")]) == 0
    out = capsys.readouterr().out
    assert "icp" in out and (tmp_path / "t" / "table1.md").is_file()
    assert main(["preview", "--data", str(d), "--count", "2", "--out", str(tmp_path / "p.png")]) == 0
    assert (tmp_path / "p.png").stat().st_size > 4_000  # drawn (a blank 256-colour PNG is about 1 KB)
    assert main(["predict", "--method", "nope", "--data", str(d), "--out", str(tmp_path / "x.npz")]) == 2
    # LABEL=FILE: a file's predictions as a row of its own name (two variants of one method side by side)
    from scapo.eval.predictions import Predictions

    other = Predictions.load(tmp_path / "p.npz")
    other.joint_state = other.joint_state + 0.1
    other.save(tmp_path / "q.npz")
    capsys.readouterr()
    assert main(["evaluate", "--data", str(d), "--pred", f"first={tmp_path / 'p.npz'}", f"second={tmp_path / 'q.npz'}",
                 "--out", str(tmp_path / "t2")]) == 0
    table = (tmp_path / "t2" / "table1.md").read_text()
    assert "| first |" in table and "| second |" in table and "| icp |" not in table
    assert main(["evaluate", "--data", str(d), "--pred", f"a/b={tmp_path / 'p.npz'}"]) == 2
    assert "LABEL a plain name" in capsys.readouterr().err


def test_a_command_takes_its_commit_as_it_starts(capsys, monkeypatch):
    """Provenance records the commit of the code a process loaded: every command takes it before its work, so
    edits to the checkout while a long bench runs do not change what its later cells record."""
    from scapo import provenance

    provenance.git_commit.cache_clear()
    calls = []
    monkeypatch.setattr(provenance.subprocess, "run", lambda *a, **k: calls.append(a[0]) or
                        subprocess.CompletedProcess(a[0], 0, stdout="abc123\n" if "rev-parse" in a[0] else ""))
    assert main(["list"]) == 0
    assert ["git", "rev-parse", "HEAD"] in calls  # taken during the command...
    n = len(calls)
    assert provenance.provenance()["commit"] == "abc123" and len(calls) == n  # ...and reused afterwards
    provenance.git_commit.cache_clear()


def test_the_console_script_ignores_ctrl_c_once_the_command_is_done(capsys):
    """``scapo`` (the console script) is :func:`main` and then ignores Ctrl-C while the interpreter shuts down: a
    Ctrl-C during torch's exit hooks once printed a traceback after the command had finished."""
    import signal

    from scapo.cli.main import console

    before = signal.getsignal(signal.SIGINT)
    try:
        assert console(["list"]) == 0
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, before)
    assert "laptop" in capsys.readouterr().out
