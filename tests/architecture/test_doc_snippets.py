"""Every example of the README, docs/behaviors.md, experiments.md, simulator.md and tutorial.md runs
(tests/architecture/doc_snippets.py).

- Python blocks are imported as modules: every behavior class they define must pass the config
  loader's checks as a plugin (``module:Class``), and every ``test_*`` function they define is run.
- TOML blocks are loaded the way antalate loads them: an agent config (a fragment of ``[[bma]]`` or
  ``[[bma.behaviors]]`` completed into a whole config) by ``load_config`` and every plugin check, an
  experiment script by ``load_script``, a ``pyproject.toml`` fragment's entry points by importing them.
- Shell blocks of the other docs: every ``antalate`` command is parsed by
  antalate's parser and what it names (a config, an experiment) is checked as the command would
  before starting; ``make`` targets, repository scripts, examples and extras must exist.
- docs/tutorial.md runs for real, in a private network namespace, in a temporary folder: its shell
  blocks in order, its ``<!-- file: PATH -->`` blocks written to PATH, its other Python blocks run;
  ``<!-- check: ... -->`` blocks are checked like the README's commands. ``pip install -e DIR`` is
  the one command rewritten: into a folder of the test's (``--target``) instead of the test's own
  environment, which it must not change.
"""

from __future__ import annotations

import importlib
import inspect
import os
import re
import shlex
import sys
from pathlib import Path
from typing import Any

import pytest
import tomli_w

from tests import REPO

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - the oldest supported Python
    import tomli as tomllib

from antalate_lcm.core.behavior import Behavior
from antalate_lcm.core.config import load_config
from antalate_lcm.runtime.agent import validate
from antalate_lcm.runtime.script import load_script
from tests.architecture.doc_snippets import Block, blocks, check_antalate, commands, is_antalate

DOCS = ["README.md", "docs/behaviors.md", "docs/experiments.md", "docs/simulator.md"]
TUTORIAL = "docs/tutorial.md"
#: What the docs' Python blocks import besides antalate: the worked example's package.
EXAMPLE_PATHS = [REPO / "examples" / "my_behavior"]


def _of(lang: set[str], docs: list[str]) -> list[Block]:
    return [b for d in docs for b in blocks(d) if b.lang in lang]


def _ids(bs: list[Block]) -> list[str]:
    return [b.id for b in bs]


@pytest.fixture
def importable(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    for path in [tmp_path, *EXAMPLE_PATHS]:
        monkeypatch.syspath_prepend(str(path))
    return tmp_path


# ----------------------------------------------------------------------------- python
PYTHON = _of({"python"}, DOCS)


@pytest.mark.parametrize("block", PYTHON, ids=_ids(PYTHON))
def test_python_blocks_import_and_their_behaviors_load(block: Block, importable: Path) -> None:
    module = "doc_snippet_" + re.sub(r"\W", "_", block.id)
    (importable / f"{module}.py").write_text(block.text)
    mod = importlib.import_module(module)
    plugins = [
        name
        for name, obj in vars(mod).items()
        if inspect.isclass(obj) and issubclass(obj, Behavior) and obj.__module__ == module
    ]
    tests = [obj for name, obj in vars(mod).items() if name.startswith("test_") and callable(obj)]
    assert plugins or tests, f"{block.id}: neither a behavior nor a test: what does this example show?"
    for name in plugins:
        doc = {"bma": [{"name": "m", "behaviors": [{"plugin": f"{module}:{name}"}]}]}
        _load(importable / f"{name}.toml", doc)
    for test in tests:
        test()


# ----------------------------------------------------------------------------- toml
TOML = _of({"toml"}, DOCS)


def _load(path: Path, doc: dict[str, Any]) -> None:
    path.write_text(tomli_w.dumps(doc))
    validate(load_config(path))


@pytest.mark.parametrize("block", TOML, ids=_ids(TOML))
def test_toml_blocks_load(block: Block, importable: Path) -> None:
    doc = tomllib.loads(block.text)
    if "project" in doc:  # a pyproject.toml fragment: its entry points resolve
        from importlib.metadata import EntryPoint

        groups = doc["project"]["entry-points"]
        assert groups, block.id
        for group, points in groups.items():
            for name, value in points.items():
                assert EntryPoint(name, value, group).load(), (block.id, name)
        return
    if "seeds" in doc or "parameters" in doc:  # an antalate sweep spec
        from antalate_lcm.runtime.sweep_spec import parse_spec

        parse_spec(doc, block.id)
        return
    if "mission_time" in doc:
        path = importable / "script.toml"
        path.write_text(block.text)
        load_script(str(path))
        return
    if isinstance(doc.get("bma"), dict):  # [[bma.behaviors]] alone: the entries of one arbiter
        doc["bma"] = [{"name": "snippet", **doc["bma"]}]
    _load(importable / "snippet.toml", doc)


# ----------------------------------------------------------------------------- shell
SHELL = _of({"sh", "bash", "console"}, DOCS)
_MAKE_TARGET = re.compile(r"^([\w.-]+):", re.M)


def _check_command(
    words: list[str], where: str, generated: frozenset[str] = frozenset(), folder: str = "."
) -> None:
    """``generated``: the files an ``antalate new behavior`` earlier in the block writes; a command
    naming one (from ``folder``, where the block's ``cd`` went) is parsed only: the tutorial's test
    installs and flies such a package for real."""
    named = {os.path.normpath(os.path.join(folder, w)) for w in words}
    if is_antalate(words):
        check_antalate(words[1:], REPO, parse_only=bool(generated & named))
    elif words[0] == "make":
        targets = set(_MAKE_TARGET.findall((REPO / "Makefile").read_text()))
        assert set(words[1:]) <= targets, f"{where}: make {' '.join(words[1:])}: not a Makefile target"
    elif words[0] == "pip" or words[1:3] == ["-m", "pip"]:
        pyproject = tomllib.loads((REPO / "pyproject.toml").read_text())
        extras = set(pyproject["project"]["optional-dependencies"])
        for word in words:
            if m := re.fullmatch(r"antalate\[([\w,-]+)\]", word):
                assert set(m[1].split(",")) <= extras, f"{where}: {word}: no such extra"
            elif word not in {"pip", "install", "-e", "-q"} and not word.startswith("antalate"):
                assert word in generated or (REPO / word).exists(), (
                    f"{where}: pip install {word}: no such folder"
                )
    for word in words[1:]:  # repository files named by the command
        if re.match(r"(examples|containers|benchmarks|tools|docs)/", word):
            assert (REPO / word).exists(), f"{where}: {word} does not exist"
    if words[0].endswith("python") and len(words) > 1 and words[1].endswith(".py"):
        assert (REPO / words[1]).is_file(), f"{where}: {words[1]} does not exist"


def _generated(words: list[str]) -> set[str]:
    """The files ``antalate new behavior NAME [--dir D]`` writes (nothing for another command)."""
    if not (is_antalate(words) and words[1:3] == ["new", "behavior"]):
        return set()
    from antalate_lcm.cli import build_parser
    from antalate_lcm.runtime.scaffold import files

    ns = build_parser().parse_args(words[1:])
    root = os.path.normpath(os.path.join(ns.dir, ns.name))
    return {root} | {os.path.normpath(os.path.join(root, rel)) for rel in files(ns.name)}


@pytest.mark.parametrize("block", SHELL, ids=_ids(SHELL))
def test_shell_commands_parse_and_name_what_exists(block: Block) -> None:
    generated: set[str] = set()
    folder = "."
    for words in commands(block.text):
        if words[0] == "cd":
            folder = os.path.normpath(os.path.join(folder, words[1]))
            assert folder in generated or (REPO / folder).is_dir(), f"{block.id}: cd {words[1]}"
            continue
        generated |= _generated(words)
        _check_command(words, block.id, frozenset(generated), folder)


def test_the_command_splitter() -> None:
    text = "sudo FOO=1 antalate run a.toml -o x.lcm  # comment\nmake setup && xvfb-run -a antalate spy \\\n  b.toml | tee\n"
    assert commands(text) == [
        ["antalate", "run", "a.toml", "-o", "x.lcm"],
        ["make", "setup"],
        ["antalate", "spy", "b.toml"],
        ["tee"],
    ]


def test_a_broken_example_fails(tmp_path: Path) -> None:
    """The checks bite: a misspelt option, a misspelt param, a missing example, a broken snippet."""
    from antalate_lcm.base.errors import ConfigError

    with pytest.raises(AssertionError, match="unrecognized arguments: --agnets"):
        check_antalate(["run", "examples/swarm_rules/gathering.toml", "--agnets", "8"], REPO)
    with pytest.raises(AssertionError, match="does not exist"):
        _check_command(["antalate", "agent", "examples/nope.toml"], "x")
    bad = tmp_path / "bad.toml"
    bad.write_text(
        (REPO / "examples/swarm_rules/gathering.toml").read_text().replace("separation =", "separaton =")
    )
    with pytest.raises(ConfigError, match=r"bma\[0\]\.behaviors\[0\]\.params\.separaton"):
        check_antalate(["run", str(bad), "--agents", "8"], tmp_path)
    (tmp_path / "doc.md").write_text(
        "x\n\n```toml\n[[bma.behaviors]]\nplugin = 'gathering'\nparams = { speed = -1 }\n```\n"
    )
    (block,) = blocks(str(tmp_path / "doc.md"))
    with pytest.raises(ConfigError, match=r"params\.speed: Input should be greater than 0"):
        test_toml_blocks_load(block, tmp_path)


# ----------------------------------------------------------------------------- the tutorial
def tutorial_script(python: str) -> str:
    """docs/tutorial.md as one bash script: files written, commands run, checks checked, in order."""
    lines = ["set -euo pipefail", 'SITE="$TUTORIAL_SITE"']
    for block in blocks(TUTORIAL):
        if block.file:
            lines += [
                f"cat > {shlex.quote(block.file)} <<'ANTALATE_DOC_EOF'",
                block.text.rstrip("\n"),
                "ANTALATE_DOC_EOF",
            ]
        elif block.lang == "python":
            lines += [f"{python} - <<'ANTALATE_DOC_EOF'", block.text.rstrip("\n"), "ANTALATE_DOC_EOF"]
        elif block.lang == "sh" and block.note.startswith("check:"):
            for words in commands(block.text):
                assert is_antalate(words), f"{block.id}: only antalate commands can be checked"
                lines.append(f"{python} -m tests.architecture.doc_snippets {shlex.join(words)}")
        elif block.lang == "sh":
            for line in block.text.splitlines():
                if m := re.match(r"\s*pip install -e (\S+)", line):
                    line = f'{python} -m pip install -q --no-deps --target "$SITE" {m[1]}'
                lines.append(line)
    return "\n".join(lines) + "\n"


@pytest.mark.netns
@pytest.mark.timeout(240)
def test_the_tutorial_runs_as_written(netns, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    from antalate_lcm.apps.analysis import analyze_log
    from tests.harness.process import child_env

    site, work = tmp_path / "site", tmp_path / "work"
    work.mkdir()
    script = tmp_path / "tutorial.sh"
    script.write_text(tutorial_script(sys.executable))
    env = child_env()
    env["PATH"] = f"{Path(sys.executable).parent}:{env['PATH']}"
    env["PYTHONPATH"] = f"{site}:{env['PYTHONPATH']}"
    env["TUTORIAL_SITE"] = str(site)
    env["XDG_STATE_HOME"] = str(tmp_path / "state")  # the swarm key's replay memory
    env["MPLBACKEND"] = "Agg"
    run = netns.run(["bash", str(script)], timeout=230, cwd=work, env=env)
    out = run.stdout + run.stderr
    print(run.stdout)  # pytest -s: the tutorial's figures, to keep its step 6 true
    if run.returncode != 0 and "No matching distribution found for setuptools" in out:
        pytest.skip("pip cannot fetch setuptools to build the package (no package index reachable)")
    assert run.returncode == 0, out[-6000:]
    pkg = work / "my_gathering"
    assert "4 passed" in run.stdout, out[-3000:]  # the tutorial's test of its pure rule
    assert "OK: 8 agent(s), all back in STANDBY" in run.stdout, out[-3000:]
    assert run.stdout.count("checked: antalate ") == 6, run.stdout
    assert (pkg / "flight.png").read_bytes()[:4] == b"\x89PNG"
    # what the tutorial says of its flight (step 6): the swarm gathered, keeping its distance
    mission = analyze_log(pkg / "flight.lcm", radius_below=6.0).phase("mission")
    assert mission is not None and mission.radius_below is not None
    assert mission.radius_below.after is not None, "the radius never fell below 6 m"
    assert mission.min_separation is not None and mission.min_separation.distance > 2.5
