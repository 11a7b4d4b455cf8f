"""Every command line in the ```bash blocks of the README and of the docs runs, as typed, through a
real bash, and what the README shows a command print is what it prints.

The files are :data:`README` and then :data:`DOC_FILES` (the docs that took over the README's
reference parts: their examples stay tested). Each example line is run with ``bash -e -o pipefail -c LINE`` in one working folder (in README order,
so files written by an example, e.g. ``shoe.rbgp``, are there for the next ones), with
``sample_data/`` linked into it and this test environment's ``rbgp`` first on PATH. Unquoted globs
are expanded by bash, pipes and redirections are bash's own. Four generic rules keep the run fast and
self-contained; nothing in them knows a particular example:

1. **Inputs that do not exist are made first**, from the sample data, by what the name looks like:
   ``DIR/`` or ``DIR/*.csv`` → a folder of three sample demonstrations (CSV), ``*.csv`` → a sample
   demonstration (it also serves as poses, starts or generated trajectories), ``*.tsv`` → a QTM
   export of a sample demonstration, ``*.mcap`` → the sample MCAP, ``*.rbgp`` → a small model,
   ``*.c3d`` → markers on a sample demonstration (:func:`sample_c3d`), ``*.bvh`` → a two-joint
   skeleton moving as one (``DIR/*.bvh``: three, :func:`sample_bvh`). Only
   relative names inside the folder are made, never values of output options or redirections.
2. **Speed options are appended** to every ``rbgp`` command (also after ``nice -n 10`` and the like)
   that accepts them and does not set them (:data:`SPEED`): fewer training points and starts,
   ``--quick``; and typed counts of repetitions above :data:`CAPS` are lowered to it. The command
   line is otherwise the README's.
3. **Installation steps** (``python3 -m venv .venv``, ``.venv/bin/pip install ...``) are the ones that
   made this test environment: they are left out of a ``&&`` chain, and ``.venv/bin/X`` is this
   environment's ``X``.
4. **The test-suite command** (it runs pytest) is not run from inside pytest: it must be exactly the
   command ``.ci/run`` runs, so CI runs it. A line that only installs is not run either.

**Shown outputs.** Where a README ```bash block is followed directly by a ```text block, that block is
what the block's last command prints (or writes, for a ``-o``/``>`` file). :data:`CHECKS` holds, per
README example, a check of its output against the README's: the columns and row labels it shows,
and value ranges (finite, non-negative, parts that add up, one row per input pose, 100 rollouts).
Every README example has a check, and every check belongs to a README example.

To keep a new README example runnable: name its inputs like the rules above (or after files an
earlier example writes), and if it is slow, give its command an option in :data:`SPEED` (or add the
command's own fast option there, or a cap for a count it types to :data:`CAPS`); a new ``rbgp``
subcommand needs nothing else.
"""

from __future__ import annotations

import glob
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
#: Docs whose ```bash examples are run too (after the README's, in this order).
DOC_FILES = [REPO / "docs" / n for n in ("commands.md", "data.md", "defaults.md", "sparse.md", "paper.md", "benchmarks.md")]
SAMPLE = REPO / "sample_data"
BIN = Path(sys.executable).parent

#: Appended to an ``rbgp`` command (option, value or None for a flag) when the command has the option
#: and the example does not set it: a smoke-test size for training, the demo's quick mode.
SPEED = (("--max-points", "120"), ("--restarts", "1"), ("--quick", None))
#: Typed values above these are lowered to them (repetitions of a benchmark).
CAPS = {"--repeats": 2}
#: Values of these options are outputs: never made beforehand.
OUTPUT_OPTIONS = {"-o", "--output", "--out", "--per-step", "--plot", "--rerun", "--markdown"}
#: File name endings that make an argument look like a path.
PATH_SUFFIXES = (".csv", ".tsv", ".mcap", ".rbgp", ".txt", ".c3d", ".bvh")


# --------------------------------------------------------------------------------------------------
# reading the README
def readme_examples(text: str) -> list[str]:
    """The command lines of every ```bash block: one per line (``\\`` continuations joined), comment-
    only and blank lines skipped."""
    out = []
    for block in re.findall(r"^```(?:bash|sh|shell)[ \t]*\n(.*?)^```", text, flags=re.M | re.S):
        joined = re.sub(r"\\\n", " ", block)
        for line in joined.splitlines():
            if line.strip() and not line.lstrip().startswith("#"):
                out.append(line.strip())
    return out


def shell_parts(line: str) -> tuple[list[tuple[int, int, int]], int]:
    """Where the simple commands of ``line`` are: per command (start, end of its words, end), split at
    unquoted ``|``, ``||``, ``&&``, ``;``; its words end at the first unquoted redirection. Also the
    position where an unquoted comment starts (len(line) if none)."""
    parts = []
    quote = None
    start, words_end = 0, None
    i, n = 0, len(line)
    comment = n
    while i < n:
        c = line[i]
        if quote:
            if c == "\\" and quote == '"':
                i += 2
                continue
            if c == quote:
                quote = None
            i += 1
            continue
        if c in "'\"":
            quote = c
        elif c == "\\":
            i += 2
            continue
        elif c == "#" and (i == 0 or line[i - 1].isspace()):
            comment = i
            break
        elif line.startswith(("&&", "||"), i) or c in "|;":
            parts.append((start, words_end if words_end is not None else i, i))
            i += 2 if line.startswith(("&&", "||"), i) else 1
            start, words_end = i, None
            continue
        elif c in "<>" and words_end is None:
            j = i
            while j > start and line[j - 1].isdigit():
                j -= 1
            words_end = j if j == start or line[j - 1].isspace() else i
        i += 1
    parts.append((start, words_end if words_end is not None else comment, comment))
    return parts, comment


def shown_outputs(text: str) -> dict[str, str]:
    """The ```text block that directly follows a ```bash block, keyed by that block's last command."""
    out = {}
    for block, shown in re.findall(r"^```(?:bash|sh|shell)[ \t]*\n(.*?)^```[ \t]*\n\s*^```text[ \t]*\n(.*?)^```",
                                   text, flags=re.M | re.S):
        lines = readme_examples(f"```bash\n{block}```\n")
        if lines:
            out[lines[-1]] = shown
    return out


def is_install_step(words: list[str]) -> bool:
    if words[:3] in (["python3", "-m", "venv"], ["python", "-m", "venv"]):
        return True
    return len(words) >= 2 and Path(words[0]).name in ("pip", "pip3") and words[1] == "install"


def runs_tests(line: str) -> bool:
    return "pytest" in line


# --------------------------------------------------------------------------------------------------
# making the example runnable
def rbgp_words(words: list[str]) -> list[str] | None:
    """The words from ``rbgp`` on (after wrappers such as ``nice -n 10`` or ``time``), or None."""
    for i, w in enumerate(words):
        if Path(w).name == "rbgp":
            return words[i:]
    return None


def _options_of(words: list[str]) -> set[str]:
    """Every option the (sub)command named by ``rbgp ...`` words accepts (nested groups followed)."""
    import typer

    from rbgp_cli.cli.app import app

    cmd = typer.main.get_command(app)
    for w in words[1:]:
        if w.startswith("-") or not hasattr(cmd, "commands"):
            continue
        nxt = cmd.commands.get(w)
        if nxt is None:
            break
        cmd = nxt
    if hasattr(cmd, "commands"):
        return set()
    return {o for p in cmd.params for o in [*getattr(p, "opts", []), *getattr(p, "secondary_opts", [])]}


def speed_options(words: list[str]) -> list[str]:
    words = rbgp_words(words)
    if words is None:
        return []
    have = _options_of(words)
    typed = {w.split("=", 1)[0] for w in words}
    extra = []
    for opt, value in SPEED:
        if opt in have and opt not in typed:
            extra += [opt] if value is None else [opt, value]
    return extra


def inputs_of(words: list[str]) -> list[str]:
    """Relative path-like arguments of an ``rbgp`` command that are not values of output options."""
    out = []
    for prev, w in zip(["", *words[:-1]], words):
        if prev in OUTPUT_OPTIONS or w.startswith("-") or w.startswith("/") or ".." in Path(w).parts:
            continue
        if w.endswith("/") or w.lower().endswith(PATH_SUFFIXES) or any(ch in w for ch in "*?["):
            out.append(w)
    return out


def make_input(name: str, folder: Path, model_path: Path) -> None:
    """Create ``name`` (relative to ``folder``) from the sample data unless something matches it."""
    if glob.glob(str(folder / name)) or (folder / name).exists():
        return
    pattern = any(ch in name for ch in "*?[")
    if name.endswith("/") or pattern:
        directory = folder / (Path(name).parent if pattern else Path(name))
        directory.mkdir(parents=True, exist_ok=True)
        if name.lower().endswith(".mcap"):
            shutil.copy(SAMPLE / "shoe_demos.mcap", directory)
        elif name.lower().endswith((".c3d", ".bvh")):
            for k, f in enumerate(sorted((SAMPLE / "csv").glob("*.csv"))[:3]):
                maker = sample_c3d if name.lower().endswith(".c3d") else sample_bvh
                maker(directory / f"take_{k + 1}{name[-4:]}", f)
        else:
            for f in sorted((SAMPLE / "csv").glob("*.csv"))[:3]:
                shutil.copy(f, directory)
        return
    target = folder / name
    target.parent.mkdir(parents=True, exist_ok=True)
    low = name.lower()
    if low.endswith((".mcap", ".csv")) and Path(name).stem.startswith("gen"):
        # what an example before it writes (rollout -o gen.csv, -o generated.mcap), which may run on another worker
        subprocess.run([str(BIN / "rbgp"), "-q", "rollout", str(model_path), "--count", "2", "-o", str(target)],
                       check=True, capture_output=True, timeout=300)
    elif low.endswith(".mcap"):
        shutil.copy(SAMPLE / "shoe_demos.mcap", target)
    elif low.endswith(".rbgp"):
        shutil.copy(model_path, target)
    elif low.endswith(".tsv"):
        from rbgp_cli.io.export import write_qtm_tsv
        from rbgp_cli.workflows import load_demonstrations

        demos, _, _ = load_demonstrations([str(SAMPLE / "csv" / "shoe_01.csv")])
        write_qtm_tsv(demos, target)
    elif low.endswith(".c3d"):
        sample_c3d(target)
    elif low.endswith(".bvh"):
        sample_bvh(target)
    else:
        shutil.copy(SAMPLE / "csv" / "shoe_01.csv", target)


def _sample_poses(csv_path=None):
    """``(t, R_world_body (N, 3, 3), p (N, 3) metres)`` of a sample demonstration, read as train reads it."""
    from scipy.spatial.transform import Rotation

    from rbgp_cli.workflows import load_demonstrations

    (demo,), _, _ = load_demonstrations([str(csv_path or SAMPLE / "csv" / "shoe_01.csv")])
    return demo.t, Rotation.from_quat(demo.quat).as_matrix(), demo.position


def sample_c3d(target: Path, csv_path=None) -> None:
    """A C3D file on a sample demonstration's motion: four markers ``boite:m1..m4`` on the body, four
    ``RTH1..RTH4`` on a second body that also turns about its own z, and the body's pose as the stored
    6-DOF segment ``pelvis``; 0.2 mm noise; the demonstration's median rate."""
    from scipy.spatial.transform import Rotation

    from tests.io.test_c3d import write_c3d

    t, rot, pos = _sample_poses(csv_path)
    rng = np.random.default_rng(0)
    box = np.array([[0.0, 0, 0], [0.2, 0, 0], [0, 0.15, 0], [0.05, 0.05, 0.1]])
    spin = Rotation.from_rotvec(np.outer(np.linspace(0, 1.5, len(t)), [0.0, 0.0, 1.0])).as_matrix()
    markers = np.concatenate([np.einsum("fij,nj->fni", rot, box) + pos[:, None],
                              np.einsum("fij,nj->fni", rot @ spin, box * 0.8) + pos[:, None] + [0.3, 0, 0]], axis=1)
    markers += rng.normal(0, 2e-4, markers.shape)
    mats = np.zeros((4, 4, 1, len(t)))
    mats[:3, :3, 0] = rot.transpose(1, 2, 0)
    mats[:3, 3, 0] = pos.T * 1e3
    mats[3, 3, 0] = 1.0
    labels = [f"boite:m{k + 1}" for k in range(4)] + [f"RTH{k + 1}" for k in range(4)]
    import tests.io.test_c3d as c3d_tests

    rate, c3d_tests.RATE = c3d_tests.RATE, float(round(1.0 / np.median(np.diff(t))))
    try:
        write_c3d(target, labels, markers, rotations=mats, rotation_labels=["pelvis"])
    finally:
        c3d_tests.RATE = rate


def sample_bvh(target: Path, csv_path=None) -> None:
    """A BVH skeleton (cm, ZXY channels) whose root moves as a sample demonstration and carries a
    joint ``Hand_R`` 60 cm along its x axis."""
    from scipy.spatial.transform import Rotation

    t, rot, pos = _sample_poses(csv_path)
    zxy = Rotation.from_matrix(rot).as_euler("ZXY", degrees=True)
    rows = [" ".join(f"{v:.6f}" for v in (*p * 100, *a, 0.0, 0.0, 0.0)) for p, a in zip(pos, zxy)]
    target.write_text(
        "HIERARCHY\nROOT joint_Root\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation "
        "Yrotation\n JOINT Hand_R\n {\n  OFFSET 60 0 0\n  CHANNELS 3 Zrotation Xrotation Yrotation\n  End Site\n  {\n"
        "   OFFSET 10 0 0\n  }\n }\n}\nMOTION\n"
        f"Frames: {len(rows)}\nFrame Time: {float(np.median(np.diff(t))):.7f}\n" + "\n".join(rows) + "\n")


def runnable(line: str, folder: Path, model_path: Path) -> str:
    """The example line with installation steps left out, ``.venv/bin/`` pointing at this environment,
    speed options appended, and its missing inputs made in ``folder``."""
    parts, comment = shell_parts(line)
    pieces = []
    for k, (start, words_end, end) in enumerate(parts):
        words = shlex.split(line[start:words_end])
        if is_install_step(words):
            continue
        seg = line[start:end].strip()
        rbgp = rbgp_words(words)
        if rbgp:
            for name in inputs_of(rbgp[1:]):
                make_input(name, folder, model_path)
            head = line[start:words_end].rstrip()
            for opt, cap in CAPS.items():
                head = re.sub(rf"(?<!\S){re.escape(opt)}(\s+|=)(\d+)(?!\S)",
                              lambda m: f"{opt}{m.group(1)}{min(int(m.group(2)), cap)}", head)
            extra = speed_options(words)
            seg = (head + "".join(" " + e for e in extra) + " " + line[words_end:end]).strip()
        sep = line[end:end + 2] if k + 1 < len(parts) else ""
        sep = sep if sep in ("&&", "||") else sep[:1]
        pieces.append((seg, sep))
    text = ""
    for seg, sep in pieces:
        text += seg + (f" {sep} " if sep else "")
    text = re.sub(r"\s*(&&|\|\||;)\s*$", "", text.strip())
    return re.sub(r"(?<![\w/.])\.venv/bin/", str(BIN) + "/", text)


def only_installs(line: str) -> bool:
    parts, _ = shell_parts(line)
    return all(is_install_step(shlex.split(line[a:b])) for a, b, _ in parts)


# --------------------------------------------------------------------------------------------------
# what the README shows the commands print
def _rows(text: str) -> list[list[str]]:
    return [ln.split() for ln in text.strip().splitlines() if ln.strip()]


def _numbers(cells) -> np.ndarray:
    vals = np.array([float(c) for c in cells if c not in ("-", "–")])
    assert np.all(np.isfinite(vals)), cells
    return vals


def _read_csv(path: Path):
    import pandas as pd

    return pd.read_csv(path, comment="#", dtype={"trajectory": str})


def check_demo(res, folder, shown):
    shown_rows, rows = _rows(shown), _rows(res.stdout)
    assert rows[0] == shown_rows[0]  # the columns the README shows
    assert [r[0] for r in rows[1:]] == [r[0] for r in shown_rows[1:]] == ["axis-angle", "euler", "quaternion"]
    for r in rows[1:]:
        mean, rot, trans, *times = _numbers(r[1:])
        assert min(mean, rot, trans, *times) >= 0 and abs(mean - rot - trans) <= 0.0015, r  # the parts add up
    assert (folder / "rbgp-demo").is_dir()


def check_inspect(res, folder, shown):
    out = res.stdout
    assert "sample_data/csv/shoe_01.csv: generic CSV" in out and "sample_data/shoe_demos.mcap: MCAP" in out
    assert "640 samples" in out and "179 Hz" in out and "/shoe/trial_01/pose" in out


def check_train(res, folder, shown):
    assert (folder / "shoe.rbgp").read_bytes()[:2] == b"PK"  # an npz (zip)
    assert "demonstrations: 9" in res.stderr and "axis-angle, kernel se-chordal" in res.stderr


def check_info(res, folder, shown):
    assert "representation: axis-angle" in res.stdout
    assert "outputs: wx, wy, wz, vx, vy, vz" in res.stdout and "input: sample_data/csv/shoe_01.csv" in res.stdout


def check_predict(res, folder, shown):
    header = shown.strip().splitlines()[0].split(",")
    out, poses = _read_csv(folder / "velocities.csv"), _read_csv(folder / "poses.csv")
    assert list(out.columns) == header and len(out) == len(poses) > 100
    stds = out[[c for c in header if c.startswith("std_")]].to_numpy()
    assert np.all(np.isfinite(out.to_numpy())) and np.all(stds > 0)


def check_rollout(res, folder, shown):
    comment, header = shown.strip().splitlines()[:2]
    lines = (folder / "gen.csv").read_text().splitlines()
    assert lines[0] == comment and lines[1] == header
    gen = _read_csv(folder / "gen.csv")
    names = gen["trajectory"].astype(str).unique()
    means = [n for n in names if "." not in n]
    assert len(means) == 100 and sorted(names) == sorted(means + [f"{n}.s0" for n in means])  # --count 100 --samples 1
    assert np.allclose(np.linalg.norm(gen[["qx", "qy", "qz", "qw"]].to_numpy(), axis=1), 1, atol=1e-9)
    first = gen.groupby("trajectory", sort=False)["t"]
    assert np.all(first.min() == 0) and np.all(first.apply(lambda t: np.all(np.diff(t) > 0)))
    mean_rows = ~gen["trajectory"].astype(str).str.contains(".", regex=False)
    assert np.all(gen[mean_rows].filter(like="std_").to_numpy() >= 0) and set(gen[mean_rows]["left_data"].unique()) <= {0, 1}
    assert gen[~mean_rows].filter(like="std_").isna().all().all()  # a sample is one motion: no std of its own


EVALUATE = re.compile(r"bhattacharyya mean (\S+)  rotation (\S+)  translation (\S+)  offset (\S+)  spread (\S+)  "
                      r"\((\d+) steps, (\d+) generated, (\d+) demonstrations\); (\d+) of (\d+) generated left the "
                      r"demonstrations' envelope")


def check_evaluate(res, folder, shown):
    assert EVALUATE.fullmatch(shown.strip()), shown  # the README's line has the form checked here
    m = EVALUATE.fullmatch(res.stdout.strip())
    assert m, res.stdout
    mean, rot, trans, offset, spread = (float(m.group(k)) for k in (1, 2, 3, 4, 5))
    assert min(mean, rot, trans, offset, spread) >= 0
    assert abs(mean - rot - trans) <= 1.5e-4 and abs(mean - offset - spread) <= 1.5e-4
    n_gen = _read_csv(folder / "gen.csv")["trajectory"].nunique()
    assert int(m.group(7)) == int(m.group(10)) == n_gen and int(m.group(8)) == 9 and int(m.group(9)) <= n_gen
    assert (folder / "fig.png").read_bytes()[:4] == b"\x89PNG"


def check_crossval(res, folder, shown):
    header = shown.strip().split()
    lines = res.stdout.splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.split()[:1] == ["representation"])
    assert lines[start].split() == header
    end = next((i for i in range(start + 1, len(lines)) if not lines[i].strip()), len(lines))  # the table ends
    rows = {r[0]: dict(zip(header, r)) for r in _rows("\n".join(lines[start + 1:end]))}  # at a blank line
    assert {"axis-angle", "euler", "quaternion", "replay"} <= set(rows)
    assert "paired against " in "\n".join(lines[end:])  # the paired comparisons below it
    floors = {float(r["floor"]) for r in rows.values()}
    assert len(floors) == 1  # one floor for every row: the same folds
    for r in rows.values():
        assert float(r["score"]) >= 0 and float(r["ratio"]) == pytest.approx(float(r["score"]) / float(r["floor"]), abs=0.006)
        assert 0 <= float(r["pos_m"]) < 1 and 0 <= float(r["rot_rad"]) < np.pi
    for name in ("axis-angle", "euler", "quaternion"):  # rbgp's bands: coverage ± its SE over the motions
        for key in ("cov_pos", "cov_rot"):
            cov, se = (float(x) for x in rows[name][key].split("±"))
            assert 0 <= cov <= 1 and 0 <= se < 0.5


def check_bench(res, folder, shown):
    assert "Theorem 1" in res.stdout and "false: smallest Gram eigenvalue -0.178 at λ = 2" in res.stdout


#: README example -> check of what it printed or wrote (``res``: the finished process, the folder it ran
#: in, the README's shown output or None).
CHECKS = {
    'python3 -m venv .venv && .venv/bin/pip install ".[plot]" && .venv/bin/rbgp demo': check_demo,
    "rbgp inspect sample_data/csv/shoe_01.csv sample_data/shoe_demos.mcap": check_inspect,
    "rbgp train sample_data/csv/*.csv -o shoe.rbgp": check_train,
    "rbgp info shoe.rbgp": check_info,
    "rbgp predict shoe.rbgp poses.csv > velocities.csv": check_predict,
    "rbgp rollout shoe.rbgp --from-demos sample_data/csv/*.csv --count 100 --samples 1 -o gen.csv": check_rollout,
    "rbgp evaluate gen.csv --demos sample_data/csv/*.csv --plot fig.png": check_evaluate,
    "rbgp crossval sample_data/csv --representation all --folds 3": check_crossval,
    "rbgp bench paper theorem": check_bench,
}

# --------------------------------------------------------------------------------------------------
README_TEXT = README.read_text(encoding="utf-8")
README_EXAMPLES = readme_examples(README_TEXT)
SHOWN = shown_outputs(README_TEXT)
EXAMPLES = list(dict.fromkeys(README_EXAMPLES + [e for doc in DOC_FILES  # a docs line the README has runs once
                                                  for e in readme_examples(doc.read_text(encoding="utf-8"))]))


def test_the_readme_has_examples_and_its_test_command_is_what_ci_runs():
    assert len(README_EXAMPLES) >= 8 and len(EXAMPLES) >= 30, EXAMPLES
    ci = (REPO / ".ci" / "run").read_text(encoding="utf-8")
    ci_commands = [ln.strip() for ln in ci.splitlines() if "pytest" in ln]
    tests = [e for e in EXAMPLES if runs_tests(e)]
    assert tests and all(t in ci_commands for t in tests), (tests, ci_commands)


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("readme")
    (folder / "sample_data").symlink_to(SAMPLE, target_is_directory=True)
    return folder


@pytest.fixture(scope="module")
def small_model(tmp_path_factory):
    from typer.testing import CliRunner

    from rbgp_cli.cli.app import app

    path = tmp_path_factory.mktemp("model") / "small.rbgp"
    res = CliRunner().invoke(app, ["-q", "train", str(SAMPLE / "csv"), "-o", str(path), "--max-points", "120",
                                   "--restarts", "1", "--share-hyperparameters"])
    assert res.exit_code == 0, res.stderr
    return path


def test_every_readme_example_has_an_output_check_and_every_check_an_example():
    run = [e for e in README_EXAMPLES if not runs_tests(e) and not only_installs(e)]
    assert sorted(run) == sorted(CHECKS), (set(run) ^ set(CHECKS))
    assert set(SHOWN) <= set(CHECKS) and len(SHOWN) >= 5, sorted(SHOWN)


def test_a_line_that_only_installs_installs_an_extra_of_this_project():
    import tomllib

    extras = set(tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["optional-dependencies"])
    installs = [e for e in README_EXAMPLES if only_installs(e)]
    assert installs, README_EXAMPLES
    for line in installs:
        for name in re.findall(r"""pip install (?:-e )?["']?\.\[([\w,-]+)\]""", line):
            assert set(name.split(",")) <= extras, line


@pytest.mark.slow
@pytest.mark.parametrize("line", [e for e in EXAMPLES if not runs_tests(e) and not only_installs(e)],
                         ids=lambda e: " ".join(e.split()[:4])[:60])
@pytest.mark.slow
def test_readme_example_runs(line, workdir, small_model):
    command = runnable(line, workdir, small_model)
    assert command, line
    env = dict(os.environ, PATH=f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}", COLUMNS="120")
    res = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", command], cwd=workdir, env=env,
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, f"{line}\nran: {command}\nstderr:\n{res.stderr[-3000:]}"
    assert "Traceback" not in res.stderr and "rbgp: error" not in res.stderr, res.stderr[-3000:]
    if line in README_EXAMPLES:
        CHECKS[line](res, workdir, SHOWN.get(line))


# --------------------------------------------------------------------------------------------------
# the rules themselves
def test_rules_keep_the_command_line_and_make_what_is_missing(tmp_path, small_model):
    (tmp_path / "sample_data").symlink_to(SAMPLE, target_is_directory=True)
    line = "rbgp train data/*.csv -o m.rbgp --json > summary.json   # a comment | not a pipe"
    cmd = runnable(line, tmp_path, small_model)
    assert cmd == "rbgp train data/*.csv -o m.rbgp --json --max-points 120 --restarts 1 > summary.json"
    assert sorted(p.name for p in (tmp_path / "data").iterdir()) == ["shoe_01.csv", "shoe_02.csv", "shoe_03.csv"]
    assert not (tmp_path / "m.rbgp").exists() and not (tmp_path / "summary.json").exists()

    cmd = runnable("rbgp rollout m2.rbgp --count 3 -o - | rbgp evaluate - --demos sample_data/csv --plot f.png",
                   tmp_path, small_model)
    assert cmd == "rbgp rollout m2.rbgp --count 3 -o - | rbgp evaluate - --demos sample_data/csv --plot f.png"
    assert (tmp_path / "m2.rbgp").read_bytes() == small_model.read_bytes() and not (tmp_path / "f.png").exists()

    cmd = runnable('python3 -m venv .venv && .venv/bin/pip install ".[plot]" && .venv/bin/rbgp demo', tmp_path, small_model)
    assert cmd == f"{BIN}/rbgp demo --quick"
    cmd = runnable("rbgp train sample_data/shoe_demos.mcap --topic '/shoe/*' -o s.rbgp", tmp_path, small_model)
    assert cmd.endswith("--topic '/shoe/*' -o s.rbgp --max-points 120 --restarts 1")
    assert not Path("/shoe").exists()
    cmd = runnable("nice -n 10 rbgp bench paper --repeats 300 --seed 0 --json > p.json", tmp_path, small_model)
    assert cmd == "nice -n 10 rbgp bench paper --repeats 2 --seed 0 --json --quick > p.json"
    runnable("rbgp inspect export.tsv poses.csv d/", tmp_path, small_model)
    assert (tmp_path / "export.tsv").read_text().startswith("FILE_VERSION")
    assert (tmp_path / "poses.csv").read_text().startswith("t,x,y,z")
    assert len(list((tmp_path / "d").glob("*.csv"))) == 3


@pytest.mark.slow
def test_the_scores_the_readme_shows_are_what_the_full_size_commands_print(tmp_path):
    """The smoke-size run above checks the form of the shown outputs; here the README's main-job and
    evaluate examples run at their full size (the defaults, 100 rollouts), and every score they print is
    the one the README shows, to one unit of its last printed digit."""
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"}
    (tmp_path / "sample_data").symlink_to(SAMPLE)

    def sh(line):
        res = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", line], cwd=tmp_path, env=env,
                             capture_output=True, text=True, timeout=900)
        assert res.returncode == 0, res.stderr
        return res.stdout

    evaluate = next(c for c in CHECKS if c.startswith("rbgp evaluate"))
    for line in [c for c in CHECKS if c.startswith(("rbgp train", "rbgp rollout"))] + [evaluate]:
        out = sh(line + " -q")
    got, shown = EVALUATE.fullmatch(out.strip()), EVALUATE.fullmatch(SHOWN[evaluate].strip())
    np.testing.assert_allclose([float(got.group(k)) for k in range(1, 6)], [float(shown.group(k)) for k in range(1, 6)],
                               atol=1.01e-4, err_msg=f"README shows {SHOWN[evaluate].strip()!r}, rbgp prints {out.strip()!r}")
    demo = next(c for c in CHECKS if c.endswith("rbgp demo"))
    printed = {r[0]: _numbers(r[1:4]) for r in _rows(sh("rbgp demo -q"))[1:]}
    for r in _rows(SHOWN[demo])[1:]:
        np.testing.assert_allclose(printed[r[0]], _numbers(r[1:4]), atol=1.01e-3, err_msg=r[0])
