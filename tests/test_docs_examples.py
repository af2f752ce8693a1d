"""The documentation against the code (README.md and docs/*.md).

- Every ```python block runs in a fresh interpreter (a temporary working folder, ``WANDB_MODE=disabled``).
  A block that names ``runs/quickstart/`` finds the checkpoints and datasets of one ``vtlearn quickstart
  --tiny`` run there. An API sketch whose inputs are left to the reader (``model_points``, ``clouds``...)
  gets them from ``SETUP``, code run before the block in the same interpreter; ``EXPECT`` holds the output
  that a block's comments claim.
- Every ``vtlearn ...`` and ``python train.py ...`` line of a shell block is parsed, not run, by the real
  parsers (``vtlearn.cli.build_parser`` and train.py's ``VtlearnCLI`` with instantiation and the run
  switched off): a flag renamed or removed in the code but still shown in the docs fails. A comment line
  right below a command that lists more options (``#   --trials 10 --frames 20  what they do``) is parsed
  with that command. ``[...]`` marks optional parts, which are included; ``a|b|c`` is tried per alternative.
- Every inline ``vtlearn ...`` code span of the prose (the README's command table among them, which uses
  placeholders such as ``N`` and ``DIR``) must name an existing command and only its options; one that
  gives values and no placeholders parses in full. An inline ``python train.py ...`` span parses.
- Repository paths the docs name (``configs/cpu/actor.yaml``, ``vtlearn/active/occupancy.py``) exist, and
  dotted names (``vtlearn.sim_data.fixtures.make_tiny_dataset``) resolve.

Block cases are keyed by (file, index among the file's python blocks) in ``SLOW`` / ``SKIP`` / ``XFAIL``;
command cases by ``file:line`` in ``COMMAND_XFAIL``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import io
import itertools
import os
import re
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOC_FILES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
FENCE = re.compile(r"^\s*```\s*(\S*)\s*$")
SHELL_LANGS = ("bash", "sh", "shell", "console", "")
QUICKSTART = "runs/quickstart"


# --------------------------------------------------------------------------------------------- extraction


@dataclass(frozen=True)
class Block:
    file: str  # relative to the repository root
    line: int  # of the opening fence
    lang: str
    index: int  # among the file's blocks of the same kind (python / shell)
    lines: tuple[str, ...]

    @property
    def key(self) -> tuple[str, int]:
        return self.file, self.index

    @property
    def text(self) -> str:
        return "\n".join(self.lines) + "\n"


def fenced_blocks(path: Path) -> list[Block]:
    """The fenced code blocks of a markdown file, in order."""
    blocks: list[Block] = []
    counts: dict[str, int] = {}
    lang, start, buf = None, 0, []
    for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        m = FENCE.match(line)
        if lang is None and m:
            lang, start, buf = m.group(1).lower(), n, []
        elif lang is not None and line.strip() == "```":
            kind = "shell" if lang in SHELL_LANGS else lang
            blocks.append(Block(str(path.relative_to(ROOT)), start, lang, counts.get(kind, 0), tuple(buf)))
            counts[kind] = counts.get(kind, 0) + 1
            lang = None
        elif lang is not None:
            buf.append(line)
    assert lang is None, f"{path.name}:{start}: unclosed code fence"
    return blocks


def python_blocks() -> list[Block]:
    return [b for f in DOC_FILES for b in fenced_blocks(f) if b.lang == "python"]


@dataclass(frozen=True)
class Command:
    file: str
    line: int  # of the command's first line in the markdown file
    kind: str  # "vtlearn" or "train"
    argv: tuple[str, ...]  # after the program name
    source: str  # the documented text

    @property
    def id(self) -> str:
        return f"{self.file}:{self.line}"


_COMMAND = re.compile(
    r"^(\$\s+)?([A-Za-z_][A-Za-z0-9_]*=\S*\s+)*(?P<prog>(\S*/)?(vtlearn|python[0-9.]*))(\s|$)"
)


def split_command(text: str) -> tuple[str, list[str]] | None:
    """``(kind, arguments)`` of a documented shell line, or None when it is not a vtlearn / train.py call.
    Comments are dropped, as are leading ``VAR=value`` assignments and a ``$`` prompt."""
    m = _COMMAND.match(text.strip())
    if m is None:
        return None
    tokens = shlex.split(text.strip()[m.start("prog"):], comments=True)
    if Path(tokens[0]).name == "vtlearn":
        return "vtlearn", tokens[1:]
    if tokens[1:2] == ["train.py"]:
        return "train", tokens[2:]
    return None


def _hint_options(comment: str) -> list[str]:
    """The options a comment line lists (``#   --trials 10 --frames 20   what they do``): each flag with
    at most one value, up to the first word that is neither."""
    tokens = shlex.split(comment.lstrip("# \t"))
    out: list[str] = []
    i = 0
    while i < len(tokens) and tokens[i].startswith("--"):
        out.append(tokens[i])
        i += 1
        if i < len(tokens) and not tokens[i].startswith("--"):
            out.append(tokens[i])
            i += 1
    return out


def shell_commands() -> list[Command]:
    """The vtlearn and train.py command lines of the shell blocks (backslash continuations joined), and
    each option hint comment right below one, joined to it."""
    commands: list[Command] = []
    for path in DOC_FILES:
        for block in fenced_blocks(path):
            if block.lang not in SHELL_LANGS:
                continue
            last: Command | None = None
            i = 0
            while i < len(block.lines):
                first = i
                text = block.lines[i]
                while text.rstrip().endswith("\\") and i + 1 < len(block.lines):
                    i += 1
                    text = text.rstrip()[:-1] + " " + block.lines[i]
                i += 1
                line = block.line + 1 + first
                stripped = text.strip()
                if re.match(r"#\s+--", stripped) and last is not None:
                    hint = _hint_options(stripped)
                    commands.append(Command(block.file, line, last.kind, (*last.argv, *hint), stripped))
                    continue
                split = split_command(stripped) if stripped and not stripped.startswith("#") else None
                last = None
                if split is not None:
                    last = Command(block.file, line, split[0], tuple(split[1]), stripped)
                    commands.append(last)
    return commands


_SPAN = re.compile(r"(?<!`)`((?:\.venv/bin/)?vtlearn [^`]+|python train\.py [^`]+)`(?!`)")


def inline_commands() -> list[Command]:
    """``vtlearn ...`` and ``python train.py ...`` code spans of the prose, outside fenced blocks (``\\|``
    in a table is ``|``)."""
    out: list[Command] = []
    for path in DOC_FILES:
        in_fence = False
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if FENCE.match(line):
                in_fence = not in_fence
                continue
            if in_fence:
                continue
            for m in _SPAN.finditer(line):
                text = m.group(1).replace("\\|", "|")
                tokens = text.replace('"$@"', "").split()  # placeholders, not shell: no quoting rules
                kind, argv = ("train", tokens[2:]) if tokens[0] == "python" else ("vtlearn", tokens[1:])
                out.append(Command(str(path.relative_to(ROOT)), n, kind, tuple(argv), text))
    return out


def variants(argv: tuple[str, ...] | list[str]) -> list[list[str]]:
    """The argument lists a documented line stands for: the brackets of ``[--opt VALUE]`` dropped (the
    optional part included) and each ``a|b|c`` value tried per alternative."""
    choices: list[list[str]] = []
    for tok in argv:
        tok = tok.lstrip("[").rstrip("]")
        if not tok:
            continue
        if "|" in tok and not tok.startswith("-"):
            choices.append(tok.split("|"))
        else:
            choices.append([tok])
    return [list(c) for c in itertools.product(*choices)]


def train_variants(argv) -> list[list[str]]:
    """``variants``, with a placeholder file name (``configs/<model>.yaml``) tried for every file it
    stands for."""
    out = []
    for v in variants(argv):
        choices = [sorted(str(p.relative_to(ROOT)) for p in ROOT.glob(re.sub(r"<[^>]*>", "*", a)))
                   if "<" in a else [a] for a in v]
        assert all(choices), f"{argv}: a placeholder that names no file"
        out.extend(list(c) for c in itertools.product(*choices))
    return out


# --------------------------------------------------------------------------------------------- parsing


@functools.cache
def vtlearn_parser():
    from vtlearn.cli import build_parser

    return build_parser()


def parse_vtlearn(argv: list[str]) -> str | None:
    """None when ``vtlearn <argv>`` parses, else argparse's error message."""
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            vtlearn_parser().parse_args(argv)
    except SystemExit as exc:
        if exc.code:
            return err.getvalue().strip().splitlines()[-1] if err.getvalue().strip() else f"exit {exc.code}"
    return None


def parse_train(argv: list[str], monkeypatch) -> str | None:
    """None when ``python train.py <argv>`` parses (config files read, classes and their arguments
    checked, nothing instantiated or run), else train.py's one-line error. Runs in the repository root,
    where the documented config paths are."""
    monkeypatch.syspath_prepend(str(ROOT))
    monkeypatch.chdir(ROOT)
    monkeypatch.setattr(sys, "argv", ["train.py"])  # pytest's own arguments are not train.py's
    import train

    for method in ("_set_seed", "instantiate_classes"):  # no global seed, no model, no data
        monkeypatch.setattr(train.VtlearnCLI, method, lambda self: None)
    monkeypatch.setattr(train.VtlearnCLI, "_run_subcommand", lambda self, subcommand: None)
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = train.main(argv)
        except SystemExit as exc:  # --help, or an error that escapes main()
            code = exc.code
    if code:
        lines = [ln for ln in err.getvalue().splitlines() if ln.strip()]
        return lines[-1] if lines else f"exit {code}"
    return None


_PLACEHOLDER = re.compile(r"^[A-Z][A-Z0-9_]*$|^\.\.\.$|^<.*>$")


def check_flags(argv: list[str]) -> str | None:
    """For a line with placeholders (``--per-category N``): the command path must exist and every option
    must be one of its parser's. None when so, else what is wrong."""
    import argparse

    parser = vtlearn_parser()
    path = ["vtlearn"]
    rest = list(argv)
    while rest and not rest[0].startswith("-"):
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs:
            break
        word = rest.pop(0)
        if word in subs[0].choices:
            parser = subs[0].choices[word]
            path.append(word)
        elif _PLACEHOLDER.match(word):
            return None  # `vtlearn COMMAND --help`, `vtlearn bench NAME`: no command to check against
        else:
            return f"{' '.join(path)}: no command {word!r} (choose from {', '.join(subs[0].choices)})"
    known = parser._option_string_actions
    for tok in rest:
        if tok.startswith("-") and not re.match(r"^-\d", tok):
            flag = tok.split("=", 1)[0]
            if flag not in known:
                return f"{' '.join(path)}: unrecognized option {flag}"
    return None


# --------------------------------------------------------------------------------------------- python blocks

# Blocks that cannot run in the default test run, keyed by (file, index among its python blocks).
SLOW = {
    ("docs/runtime.md", 1): "the two-arm runtime: declutter, 20 IK-checked arm touches and perception in "
    "pybullet, about 30 s",
}
SKIP: dict[tuple[str, int], str] = {}
XFAIL: dict[tuple[str, int], str] = {}

# The inputs an API sketch leaves to the reader, run before the block in the same interpreter.
_BUNNY = """
import os
import numpy as np
import pybullet_data
from vtlearn.geometry import random_pose, transform_points
from vtlearn.io import read_geometry
_bunny = read_geometry(os.path.join(pybullet_data.getDataPath(), "bunny.obj"), n_points=1500)
_bunny = 0.15 * (_bunny - _bunny.mean(0)) / np.ptp(_bunny, axis=0).max()   # 15 cm
"""
# a crossmodal pool larger than the quickstart's (2 tactile clouds): 2 x 3 objects x 6 clouds
_CROSS_SMALL = """
import dataclasses, os
from vtlearn.sim_data.fixtures import tiny_config
from vtlearn.sim_data.writer import generate_dataset
_cfg = dataclasses.replace(tiny_config("crossmodal"), categories=["mug", "bottle"], views=1, tactile_clouds=6,
                           image_width=80, image_height=60)
generate_dataset(_cfg, "data/cross_small", workers=1, progress=False)
"""
SETUP = {
    ("docs/actor.md", 0): f"""
import os, shutil
import numpy as np
os.makedirs("runs/actor_quick/checkpoints")
shutil.copy("{QUICKSTART}/actor.ckpt", "runs/actor_quick/checkpoints/last.ckpt")
_rng = np.random.default_rng(0)
_d = _rng.normal(size=(60, 3))
sparse_points = 0.5 * _d / np.linalg.norm(_d, axis=1, keepdims=True)    # 60 touches on a sphere
padded = np.stack([sparse_points, np.pad(sparse_points[:40], ((0, 20), (0, 0)))])
lengths = np.array([60, 40])
""",
    ("docs/registration.md", 0): _BUNNY + """
model_points = _bunny
scene_points = transform_points(random_pose(seed=0), _bunny[np.random.default_rng(0).choice(1500, 80)])
""",
    ("docs/registration.md", 1): _BUNNY + """
_T_W_O = np.eye(4)
_T_W_O[:3, 3] = [0.5, 0.1, 0.05]
_P_W = transform_points(_T_W_O, _bunny)
X = random_pose(seed=3)                                   # the true hand-eye calibration
X[:3, 3] = [0.02, -0.03, 0.08]
T_W_E = np.stack([random_pose(seed=10), random_pose(seed=11)])
T_W_E[:, :3, 3] = [[0.3, 0.0, 0.5], [0.3, 0.1, 0.5]]
P_C_view0, P_C_view1 = (transform_points(np.linalg.inv(T @ X), _P_W) for T in T_W_E)
P_W_tactile = _P_W[np.random.default_rng(0).choice(len(_P_W), 60, replace=False)]
P_C, P_W = [P_C_view0, P_C_view1], P_W_tactile
nominal = X.copy()
nominal[:3, 3] += [0.01, -0.005, 0.008]
""",
    ("docs/xavtnet.md", 0): _CROSS_SMALL,
    ("docs/runtime.md", 0): """
import numpy as np
def _top(cx, cy, sx, sy, h=0.04):   # points on the top face of a box standing on the table
    u, v = np.meshgrid(np.linspace(-sx / 2, sx / 2, 20), np.linspace(-sy / 2, sy / 2, 20))
    return np.stack([cx + u.ravel(), cy + v.ravel(), np.full(u.size, h)], axis=1)
clouds = {1: _top(0.0, 0.0, 0.05, 0.05), 2: _top(0.06, 0.0, 0.03, 0.05)}
target = 1
""",
    ("docs/sim_data.md", 0): f"""
import os
os.makedirs("data")
os.symlink(os.path.abspath("{QUICKSTART}/data/reconstruction"), "data/recon_small")
""" + _CROSS_SMALL,
}

# Output that a block's comments claim, as substrings of its stdout.
EXPECT = {
    # success; the push count and distance after it vary with the host's rounding of the contact physics
    ("docs/manipulation.md", 0): ["True "],
    ("docs/xavtnet.md", 0): ["3 True\n", "3 [4, 6, 8, 10]\n"],
    ("docs/manipulation.md", 1): [
        "prismatic 5 ['push', 'push', 'hold_pull', 'hold_pull', 'hold_pull'] [-0.052", "\nrevolute\n"
    ],
}


def _python_params():
    params = []
    for b in python_blocks():
        marks = []
        if b.key in SLOW:
            marks.append(pytest.mark.slow)
        if b.key in SKIP:
            marks.append(pytest.mark.skip(reason=SKIP[b.key]))
        if b.key in XFAIL:
            marks.append(pytest.mark.xfail(strict=True, reason=XFAIL[b.key]))
        params.append(pytest.param(b, id=f"{b.file}:{b.line}", marks=marks))
    return params


def _env() -> dict[str, str]:
    env = dict(os.environ, WANDB_MODE="disabled", MPLBACKEND="Agg")
    env.setdefault("OMP_NUM_THREADS", "1")
    return env


@pytest.fixture(scope="module")
def quickstart_dir(tmp_path_factory) -> Path:
    """One ``vtlearn quickstart --tiny`` run (about 5 s): the checkpoints and data of ``runs/quickstart``."""
    out = tmp_path_factory.mktemp("docs_quickstart") / "quickstart"
    proc = subprocess.run(
        [sys.executable, "-m", "vtlearn.cli", "quickstart", "--out", str(out), "--tiny"],
        cwd=out.parent, env=_env(), capture_output=True, text=True, timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    for name in ("actor.ckpt", "xavtnet.ckpt", "data/crossmodal/manifest.json"):
        assert (out / name).is_file(), name
    return out


def run_block(block: Block, cwd: Path, quickstart: Path | None = None) -> subprocess.CompletedProcess:
    """Run a python block (after its ``SETUP``) in a fresh interpreter in ``cwd``, with ``quickstart`` as
    ``runs/quickstart`` when given."""
    if quickstart is not None:
        (cwd / "runs").mkdir()
        (cwd / "runs" / "quickstart").symlink_to(quickstart)
    script = cwd / "doc_block.py"
    # the block keeps its markdown line numbers in a traceback: the setup is compiled on the first line
    setup = SETUP.get(block.key, "")
    script.write_text(f"exec(compile({setup!r}, 'setup', 'exec'))\n" + "\n" * (block.line - 1) + block.text)
    return subprocess.run([sys.executable, str(script)], cwd=cwd, env=_env(), capture_output=True, text=True,
                          timeout=600)


def needs_quickstart(block: Block) -> bool:
    return QUICKSTART in SETUP.get(block.key, "") + block.text


@pytest.mark.parametrize("block", _python_params())
def test_python_block_runs(block: Block, tmp_path, request):
    quickstart = request.getfixturevalue("quickstart_dir") if needs_quickstart(block) else None
    t0 = time.perf_counter()
    proc = run_block(block, tmp_path, quickstart)
    where = f"{block.file}:{block.line} (python block {block.index}, {time.perf_counter() - t0:.1f} s)"
    assert proc.returncode == 0, f"{where} failed:\n{proc.stderr[-4000:]}"
    for claim in EXPECT.get(block.key, []):
        assert claim in proc.stdout, f"{where}: the docs claim {claim!r}; it printed:\n{proc.stdout[-2000:]}"


# --------------------------------------------------------------------------------------------- commands

# Command lines that cannot parse although the docs are right, keyed by "file:line": none so far.
COMMAND_XFAIL: dict[str, str] = {}


def _command_params(commands):
    return [pytest.param(c, id=f"{c.id}{' (hint)' if c.source.startswith('#') else ''}",
                         marks=[pytest.mark.xfail(strict=True, reason=COMMAND_XFAIL[c.id])]
                         if c.id in COMMAND_XFAIL else [])
            for c in commands]


@pytest.mark.parametrize("command", _command_params(shell_commands()))
def test_shell_command_parses(command: Command, monkeypatch):
    expand = variants if command.kind == "vtlearn" else train_variants
    for argv in expand(command.argv):
        error = parse_vtlearn(argv) if command.kind == "vtlearn" else parse_train(argv, monkeypatch)
        assert error is None, f"{command.id}: `{command.source}` -> {argv}: {error}"


def _has_placeholder(argv) -> bool:
    return any(_PLACEHOLDER.match(a) or "<" in a or "|" in a or a.startswith("[") or a.endswith("]")
               for a in argv)


@pytest.mark.parametrize("command", _command_params(inline_commands()))
def test_inline_command_options_exist(command: Command, monkeypatch):
    """An inline span names an existing command and only its options; one that gives values and no
    placeholders (`vtlearn bench registration --seed 1 --methods stiqf`) parses in full, apart from the
    required options that a mention in the prose leaves out."""
    if command.kind == "train":
        for argv in train_variants(command.argv):
            error = parse_train(argv, monkeypatch)
            assert error is None, f"{command.id}: `{command.source}` -> {argv}: {error}"
        return
    for argv in variants(command.argv):
        error = check_flags(argv)
        assert error is None, f"{command.id}: `{command.source}`: {error}"
    gives_values = any(a.startswith("--") and b and not b.startswith("-")
                       for a, b in zip(command.argv, (*command.argv[1:], ""), strict=True))
    if gives_values and not _has_placeholder(command.argv):
        error = parse_vtlearn(list(command.argv))
        assert error is None or "the following arguments are required" in error, (
            f"{command.id}: `{command.source}`: {error}")


def test_the_checks_can_fail(monkeypatch, tmp_path):
    """A copy of a documented line with a flag the code does not have, or a misspelt command, fails each
    check; so does a copy of a python block that calls a name the code does not have."""
    block = next(b for b in python_blocks() if not needs_quickstart(b) and "chamfer_distance(" in b.text)
    bad_block = dataclasses.replace(block, lines=tuple(ln.replace("chamfer_distance", "chamfer_dist")
                                                       for ln in block.lines))
    proc = run_block(bad_block, tmp_path)
    assert proc.returncode != 0 and "chamfer_dist" in proc.stderr
    good = next(c for c in shell_commands() if c.kind == "vtlearn" and c.argv[:1] == ("register",))
    assert parse_vtlearn(list(good.argv)) is None
    bad = [a.replace("--method", "--methd") for a in good.argv]
    assert "unrecognized arguments: --methd" in parse_vtlearn(bad)
    assert "invalid choice" in parse_vtlearn(["bench", "registraton"])
    assert check_flags(bad) == "vtlearn register: unrecognized option --methd"
    assert check_flags(["gen-date", "--out", "DIR"]).startswith("vtlearn: no command 'gen-date'")
    assert check_flags(["bench", "NAME"]) is None
    # train.py: an unknown top-level flag and a misspelt model argument
    train_cmd = next(c for c in shell_commands() if c.kind == "train")
    assert parse_train(list(train_cmd.argv), monkeypatch) is None
    assert "--bogus" in parse_train([*train_cmd.argv, "--bogus", "3"], monkeypatch)
    assert "not accepted" in parse_train([*train_cmd.argv, "--model.init_args.bogus", "3"], monkeypatch)
    # extraction: a continuation line, a trailing comment, an env prefix, optional parts and alternatives
    assert split_command("OMP_NUM_THREADS=1 .venv/bin/vtlearn bench x --a 1  # note") == (
        "vtlearn", ["bench", "x", "--a", "1"])
    assert variants(["[--method", "a|b]"]) == [["--method", "a"], ["--method", "b"]]
    assert _hint_options("#   --seq-trials 5 --seq-frames 60 Table 6.2 sequences") == [
        "--seq-trials", "5", "--seq-frames", "60"]
    assert len(train_variants(["fit", "--config", "configs/quick/<model>.yaml"])) >= 5


def test_docs_have_examples():
    """The extraction still finds what the docs hold (a changed fence style would silently test nothing)."""
    assert len(python_blocks()) >= 10
    kinds = [c.kind for c in shell_commands()]
    assert kinds.count("vtlearn") >= 40 and kinds.count("train") >= 5
    assert len(inline_commands()) >= 50


# --------------------------------------------------------------------------------------------- references

_REPO_PATH = re.compile(r"(?<![\w./-])(?:\./)?((?:vtlearn|configs|scripts|tests|docs)/[\w./*-]*[\w*])")
_DOTTED = re.compile(r"`(vtlearn(?:\.\w+)+)")


def references(pattern: re.Pattern) -> list[tuple[str, int, str]]:
    """``(file, line, match)`` of a pattern anywhere in the docs, code blocks included; placeholders
    (``<model>``) left out."""
    out = []
    for path in DOC_FILES:
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            for m in pattern.finditer(line):
                if "<" not in line[m.start():m.end() + 1]:
                    out.append((str(path.relative_to(ROOT)), n, m.group(1)))
    return out


@pytest.mark.parametrize("doc", [str(f.relative_to(ROOT)) for f in DOC_FILES])
def test_repository_paths_exist(doc):
    """Files and folders of the repository that the docs name (``configs/cpu/actor.yaml``,
    ``vtlearn/active/occupancy.py``, ``configs/actor*.yaml``) exist."""
    missing = [f"{file}:{n}: {ref}" for file, n, ref in references(_REPO_PATH)
               if file == doc and not list(ROOT.glob(ref.rstrip("/")))]
    assert not missing, "\n".join(missing)


def _resolve(dotted: str):
    """The module or attribute a dotted ``vtlearn.a.b.C`` name refers to."""
    import importlib

    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ModuleNotFoundError:
            continue
        for attr in parts[i:]:
            obj = getattr(obj, attr)
        return obj
    raise ModuleNotFoundError(dotted)


@pytest.mark.parametrize("ref", [pytest.param(r, id=f"{r[0]}:{r[1]}:{r[2]}") for r in references(_DOTTED)])
def test_dotted_names_resolve(ref):
    """``vtlearn.sim_data.fixtures.make_tiny_dataset`` and the like in the prose still exist."""
    file, n, dotted = ref
    try:
        _resolve(dotted)
    except (ImportError, AttributeError) as exc:
        pytest.fail(f"{file}:{n}: `{dotted}` does not resolve: {exc}")
