"""Verification against references independent of the finite-element code.

* ``models``: reduced (homogeneous, incompressible) reference models derived by hand from
  the free energy and solved with diffrax or in closed form; they do not use
  ``dejax.material``.
* ``cases``: the ``dejax verify`` cases, each returning ``Check`` rows, and the table.
* ``data/``: reference data shipped with the package (Project Chrono's ANCF 3843 element
  data, with its licence and provenance in ``data/chrono-ancf3843/README.md``).
"""
from pathlib import Path

DATA = Path(__file__).resolve().parent / "data"
"""Folder of the shipped reference data."""


def data_path(*parts) -> Path:
    """Path of a shipped reference file or folder; FileNotFoundError naming it when absent."""
    p = DATA.joinpath(*parts)
    if not p.exists():
        raise FileNotFoundError(f"reference data {p} is missing: it ships with dejax "
                                f"(dejax/verification/data/); reinstall the package or restore the file")
    return p
