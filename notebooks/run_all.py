"""Make the paper notebooks' runs and execute the notebooks in place, with their outputs.

    python notebooks/run_all.py                 # full size: the paper's meshes (hours on 2 cores the first time)
    python notebooks/run_all.py --small         # DEJAX_SMALL=1: tiny meshes, a few minutes; writes copies to --out
    python notebooks/run_all.py --runs-only     # only the rolled-tube runs (kept in notebooks/results/rolled/)
    python notebooks/run_all.py --notebooks paper_block

The rolled-tube runs (``paper_cases.py``) are made first, each once (a kept result is
reused; delete it to recompute); the notebooks then execute with nbclient, each in the
notebooks folder. Prints the wall time of each part and the total.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
PAPER_NOTEBOOKS = ("paper_block", "paper_rolled", "paper_torsional")


def execute(path: Path, out: Path, timeout: float = 4 * 3600) -> float:
    """Execute the notebook ``path`` (working folder: notebooks/) and write it with its
    outputs to ``out``; raises RuntimeError naming the first failing cell. Returns the wall time (s)."""
    import nbclient
    import nbformat

    nb = nbformat.read(path, as_version=4)
    tic = time.perf_counter()
    client = nbclient.NotebookClient(nb, timeout=timeout, kernel_name="python3",
                                     resources={"metadata": {"path": str(HERE)}})
    try:
        client.execute()
    except nbclient.exceptions.CellExecutionError as e:
        raise RuntimeError(f"{path.name}: a cell failed: {str(e)[-2000:]}") from None
    finally:
        out.parent.mkdir(parents=True, exist_ok=True)
        nbformat.write(nb, out)
    return time.perf_counter() - tic


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--small", action="store_true", help="reduced size (DEJAX_SMALL=1)")
    ap.add_argument("--runs-only", action="store_true", help="make the rolled-tube runs, execute no notebook")
    ap.add_argument("--notebooks", default=",".join(PAPER_NOTEBOOKS),
                    help="comma-separated notebooks to execute (default: %(default)s)")
    ap.add_argument("--out", default=None,
                    help="folder for the executed notebooks (default: in place at full size; with --small a "
                         "temporary folder, so the committed full-size outputs stay)")
    args = ap.parse_args(argv)
    if args.small:
        os.environ["DEJAX_SMALL"] = "1"
    sys.path.insert(0, str(HERE))
    import paper_cases as pc

    tic = time.perf_counter()
    print(f"rolled-tube runs ({'small' if pc.SMALL else 'full'} size) in {pc.RESULTS}", flush=True)
    runs_s = pc.run_all(log=lambda s: print("  " + s, flush=True))
    print(f"runs: {runs_s:.0f} s", flush=True)
    if not args.runs_only:
        if args.out is not None:
            out_dir = Path(args.out)
        elif args.small:
            import tempfile

            out_dir = Path(tempfile.mkdtemp(prefix="dejax-notebooks-"))
        else:
            out_dir = HERE
        for name in [n.strip() for n in args.notebooks.split(",") if n.strip()]:
            src = HERE / f"{name}.ipynb"
            if not src.exists():
                raise SystemExit(f"run_all: no notebook {src}")
            wall = execute(src, out_dir / src.name)
            print(f"{name}.ipynb executed in {wall:.0f} s -> {out_dir / src.name}", flush=True)
    print(f"total wall time: {time.perf_counter() - tic:.0f} s ({(time.perf_counter() - tic) / 60:.1f} min)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
