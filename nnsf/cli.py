"""The ``nnsf`` command: each pipeline stage as a plain command, without orchestration.

    nnsf data|features|factorize|evaluate|isomap [--params params.yaml]
    nnsf sweep [--params params.yaml]        every sweep point in turn, a CSV on stdout
    nnsf check [--params params.yaml]        validate params.yaml and exit

The same stages run as Prefect flows with MLflow logging through
``python -m flows <stage>`` (what ``dvc repro`` calls).  Exit codes: 0 done,
2 bad input (one ``error: …`` line on stderr naming the file and field),
1 anything else (one line; ``NNSF_DEBUG=1`` shows the traceback).
"""
from __future__ import annotations

import argparse
import os
import sys

from nnsf.errors import InputError

STAGES = ("data", "features", "factorize", "evaluate", "isomap")


def _one_line(exc: BaseException) -> str:
    lines = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {lines[0]}" if lines else type(exc).__name__


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="nnsf", description=__doc__.split("\n\n")[0])
    parser.add_argument("command", choices=STAGES + ("sweep", "check"))
    parser.add_argument("--params", default="params.yaml", help="parameters file (default: params.yaml)")
    args = parser.parse_args(argv)
    try:
        from nnsf import params as params_mod
        from nnsf import stages

        params = params_mod.load(args.params)
        if args.command == "check":
            print(f"{args.params}: ok")
            return 0
        if args.command == "sweep":
            import pandas as pd

            rows = []
            for point in stages.sweep_grid(params):
                res = stages.sweep_point(params, point)
                rows.append({**point, **res.metrics})
                print(f"alpha={point['alpha']:g} beta={point['beta']:g} rank={point['rank']}: "
                      f"precision {res.metrics['precision_mean']:.3f}", file=sys.stderr)
            pd.DataFrame(rows).to_csv(sys.stdout, index=False)
            return 0
        result = getattr(stages, args.command)(params)
        for key, value in result.metrics.items():
            print(f"{args.command}: {key} = {value:.6g}" if isinstance(value, float)
                  else f"{args.command}: {key} = {value}")
        return 0
    except InputError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130
    except Exception as err:  # a bug or an environment problem
        if os.environ.get("NNSF_DEBUG"):
            raise
        print(f"error: {args.command}: {_one_line(err)} (set NNSF_DEBUG=1 for the traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
