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
