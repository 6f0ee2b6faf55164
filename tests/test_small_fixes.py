"""The smaller things a user tripped on (issue 26), each shown on the real command or the README's
own text; each test failed on the code before its fix."""

from __future__ import annotations

import re
import subprocess
import sys
import textwrap

from cli_support import DATA, REPO, assert_clean_failure, run


def test_compare_writes_plain_lines_into_a_pipe(tmp_path):
    """Before: tqdm's carriage-return bar went into pipes and logs."""
    proc = run("compare", "--out", tmp_path / "c", "--methods", "conditions", "--photos", "4", "--layouts", "ends",
               "--trials", "3", "--workers", "1")
    assert proc.returncode == 0, proc.stderr
    assert "\r" not in proc.stderr
    assert re.search(r"^striptri: trials 3/3$", proc.stderr, re.M), proc.stderr


def test_an_unavailable_solver_given_on_the_command_line_is_blamed_on_it(tmp_path):
    """Before: --solver cholmod without scikit-sparse blamed project.toml."""
    code = textwrap.dedent(f"""
        import sys
        sys.modules["sksparse"] = None  # scikit-sparse not installed
        sys.modules["sksparse.cholmod"] = None
        sys.argv = ["striptri", "adjust", {str(DATA / "pair")!r}, "--out", {str(tmp_path / "o")!r},
                    "--solver", "cholmod"]
        from striptri.cli import main
        main()
    """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    err = assert_clean_failure(proc, 2)
    assert "command line (--solver)" in err and "project.toml" not in err.split(":")[2], err
    assert "scikit-sparse" in err


def test_help_texts_name_no_internal_references():
    """Before: `simulate --help` showed "[default: 0.0; x<=None]" and the help texts named "issue 18"
    and "DESIGN section 9", which a user cannot look up."""
    for command in ("simulate", "adjust", "compare", "plan", "convert", "structure"):
        text = run(command, "--help").stdout
        assert "None" not in text, (command, text)
        assert not re.search(r"issue \d|DESIGN section", text), (command, text)


def test_the_readme_python_example_runs():
    """Before: it used BundleOptions without importing it."""
    readme = (REPO / "README.md").read_text()
    block = readme.split("## Python API", 1)[1].split("\n\n", 2)[1]
    code = textwrap.dedent("\n".join(line for line in block.splitlines()))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=REPO)
    assert proc.returncode == 0, proc.stderr


def test_the_readme_names_every_method_and_format():
    readme = (REPO / "README.md").read_text()
    for method in ("conditions", "bundle", "sequential"):
        assert "--method conditions|bundle|sequential" in readme and method in readme
    assert "--to project|colmap|bal|dbat" in readme


def test_a_method_refused_on_a_block_is_bad_input(tmp_path):
    """Before: the sequential method on a block exited 1, as if the numbers had failed."""
    proc = run("adjust", DATA / "block_3x6", "--out", tmp_path / "o", "--method", "sequential")
    err = assert_clean_failure(proc, 2)
    assert "photos.csv" in err and "one strip" in err and "3 strips" in err
    assert not (tmp_path / "o").exists()


def test_the_structure_figure_names_the_photos():
    """Before: its axes counted the blocks from 0."""
    from striptri.io import read_project
    from striptri.adjustment import normal_matrix_at_approximations
    from striptri.pipeline import structure_labels

    project = read_project(DATA / "strip8")
    _, layout = normal_matrix_at_approximations(project)
    assert structure_labels(project, layout) == list(project.photos.ids)
