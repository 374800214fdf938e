"""``python -m jtraj ...``: the ``jtraj`` command (`jtraj.cli`), for an environment whose
scripts folder is not on PATH."""

__all__: list[str] = []

if __name__ == "__main__":  # (importing it, as a walk of the package does, runs nothing)
    from jtraj.cli import main

    raise SystemExit(main())
