"""``python -m pipeline``: the ``rfidstudy`` command where its entry-point script is not
installed (e.g. the package on ``PYTHONPATH`` of a machine without the project's venv)."""

if __name__ == "__main__":
    from pipeline.apps.cli import app

    app(prog_name="rfidstudy")
