"""ritactl's CLI polish (issue 35): help on every subcommand and positional, offline verbs without
network options, --keys honoured by keys init, resume --detach, completion for bash, zsh and fish.

The shells run the generated scripts themselves (bash's COMPREPLY, zsh's compadd, fish's
``complete -C``); a shell that is not installed skips its test, naming it (.ci/run installs them).
"""
from __future__ import annotations

import argparse
import shutil
import subprocess

import pytest

from daemon.ctl.completion import bash_script, fish_script, zsh_script
from daemon.ctl.io import subparsers_of
from daemon.ctl.main import build_parser, main
from tests.ctl_sim import post_job, report, sim_daemon

#: the offline verbs, each with arguments it accepts
OFFLINE = {"validate": ["f"], "recompute": ["d"], "plate survey": ["f", "--plate", "p"], "keys init": [],
           "completion": ["bash"]}


Path = tuple[str, ...]


def _paths(p: argparse.ArgumentParser, path: Path = ()) -> list[tuple[Path, argparse.ArgumentParser]]:
    out = [(path, p)]
    for name, child in subparsers_of(p).items():
        out += _paths(child, (*path, name))
    return out


PATHS = _paths(build_parser())


def test_every_subcommand_prints_its_own_help(capsys):
    """`ritactl keys init --help` printed the keys help; now each path prints its own usage line."""
    assert len(PATHS) > 40
    for path, _ in PATHS:
        assert main([*path, "--help"]) == 0, path
        out = capsys.readouterr().out
        assert out.startswith(f"usage: {' '.join(('ritactl', *path))} "), (path, out[:200])


def test_every_subcommand_positional_and_option_has_help():
    missing = []
    for path, p in PATHS:
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                missing += [(*path, c.dest) for c in a._choices_actions if not c.help]
            elif a.help is None:
                missing.append((*path, a.dest))
    assert not missing, missing


@pytest.mark.parametrize("verb", OFFLINE)
def test_offline_verbs_offer_no_network_options(verb, capsys):
    assert main([*verb.split(), "--help"]) == 0
    out = capsys.readouterr().out
    assert "--endpoint" not in out and "--timeout" not in out and "--json" in out, out
    assert main([*verb.split(), *OFFLINE[verb], "--endpoint", "ipc:///x"]) == 64
    assert "unrecognized arguments: --endpoint" in capsys.readouterr().err


def test_keys_init_writes_where_keys_points(tmp_path, monkeypatch, capsys):
    """`ritactl --keys DIR keys init` wrote to the default folder; now to DIR, as every verb reads from it."""
    monkeypatch.delenv("RITA_KEYS", raising=False)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "xdg"))
    monkeypatch.setenv("RITA_CONFIG", str(tmp_path / "none.toml"))
    assert main(["--keys", str(tmp_path / "k"), "keys", "init", "--name", "bob"]) == 0
    assert (tmp_path / "k" / "bob.key_secret").exists() and not (tmp_path / "xdg").exists()
    assert main(["--keys", str(tmp_path / "k"), "keys", "init", "--dir", str(tmp_path / "d")]) == 0
    assert (tmp_path / "d" / "client.key").exists()  # --dir still wins
    cfg = tmp_path / "ritactl.toml"
    cfg.write_text(f'keys_dir = "{tmp_path / "from-config"}"\n')
    assert main(["--config", str(cfg), "keys", "init"]) == 0
    assert (tmp_path / "from-config" / "client.key").exists()


def test_resume_detach_returns_at_once(tmp_path, capsys):
    with sim_daemon(tmp_path / "rt") as d:
        ep = d.server.endpoints[0]
        from daemon.bus.client import Client

        with Client(ep, timeout=10) as c:
            job = post_job(c)
            report(c, job, "error", {"message": "nest not found"})
        capsys.readouterr()
        assert main(["--endpoint", ep, "resume", job, "--detach"]) == 0
        assert f"job {job} resumed" in capsys.readouterr().out


def _need(shell: str) -> None:
    if shutil.which(shell) is None:
        pytest.skip(f"{shell} is not installed here (.ci/run installs it)")


#: compadd and _files stubbed to print what they are given: the zsh function runs without a terminal
ZSH_STUBS = ("compdef() {}; compadd() { [[ $1 == -- ]] && shift; print -l -- \"$@\"; }; "
             "_files() { print FILES; }\n")


def complete(shell: str, *words: str, cur: str = "", cwd: str | None = None) -> set[str]:
    """What ``shell`` offers after ``ritactl WORDS CUR<Tab>``, from the generated script."""
    n, typed = len(words), " ".join(words)
    if shell == "bash":
        argv = ["bash", "-c", f"{bash_script(build_parser())}\nCOMP_WORDS=(ritactl {typed} '{cur}'); "
                              f"COMP_CWORD={n + 1}; _ritactl; printf '%s\\n' \"${{COMPREPLY[@]}}\""]
    elif shell == "zsh":
        argv = ["zsh", "-f", "-c", f"{ZSH_STUBS}{zsh_script(build_parser())}\n"
                                   f"words=(ritactl {typed} '{cur}'); CURRENT={n + 2}; _ritactl"]
    else:
        argv = ["fish", "--no-config", "-c", f"{fish_script(build_parser())}\ncomplete -C "
                                             f"{' '.join(('ritactl', *words, cur))!r}"]
    out = subprocess.run(argv, capture_output=True, text=True, timeout=30, check=True, cwd=cwd).stdout
    return {row.split("\t")[0] for row in out.splitlines() if row}


@pytest.mark.parametrize("shell", ["bash", "zsh", "fish"])
def test_completion_completes_subcommands_options_and_values(shell, tmp_path):
    _need(shell)
    assert {"status", "tracker", "robot", "calibrate", "keys", "completion"} <= complete(shell)
    assert complete(shell, "tracker") == {"measure", "aim", "find", "stream", "status", "readback"}
    assert complete(shell, "keys") == {"init", "allow", "role", "revoke", "list"}
    assert complete(shell, "completion") == {"bash", "zsh", "fish"}  # a positional's choices
    # an option's values
    assert complete(shell, "keys", "allow", "bob.key", "--role") == {"viewer", "operator", "admin"}
    assert {"--yes", "--speed", "--no-wait", "--json"} <= complete(shell, "robot", "move", cur="--")
    assert "--endpoint" not in complete(shell, "validate", cur="--")  # an offline verb
    (tmp_path / "afile.json").write_text("{}")
    files = complete(shell, "recompute", "--out", cwd=str(tmp_path))  # a free value: file names
    # bash: an empty answer, and `complete -o default` lists the files; zsh: _files; fish: -F
    assert files == {"bash": set(), "zsh": {"FILES"}, "fish": {"afile.json"}}[shell], files
