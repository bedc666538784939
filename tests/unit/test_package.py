"""Package data: every task and model file ships with the package."""


def test_package_data_ships_every_task_and_model_file():
    """A non-editable install (pip install .) carries only the files pyproject's package-data
    names: every file the built-in tasks read (models, the cheetah's standing-torque CSV) must
    match one of its patterns."""
    import fnmatch
    import tomllib
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    pkg = root / "src" / "hydroilqr"
    pyproject = tomllib.loads((root / "pyproject.toml").read_text())
    patterns = pyproject["tool"]["setuptools"]["package-data"]["hydroilqr"]
    files = [
        p.relative_to(pkg).as_posix()
        for d in ("tasks", "models")
        for p in (pkg / d).rglob("*")
        if p.is_file() and "__pycache__" not in p.parts
    ]
    assert "tasks/cheetah_standing_torques.csv" in files
    missing = [f for f in files if not any(fnmatch.fnmatch(f, pat) for pat in patterns)]
    assert missing == []


def test_an_installed_copy_names_the_commit_it_was_built_from(tmp_path):
    """Issue 39, 11: outside a git checkout (pip install .) the code is the commit setup.py
    recorded at build time, or says honestly that it is unknown; a checkout names its own."""
    from pathlib import Path

    from hydroilqr.io import environment as report

    pkg = tmp_path / "site-packages" / "hydroilqr"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    assert report.package_code(pkg) == "installed package, commit unknown"
    (pkg / report.BUILD_COMMIT_FILE).write_text("3b8f60f\n")
    assert report.package_code(pkg) == "3b8f60f (installed build)"
    checkout = report.package_code(Path(report.__file__).parent.parent)
    assert checkout and "installed" not in checkout
