"""Prefect flows for the nnsf pipeline, with MLflow logging.

This package is the only place where the orchestration and experiment-logging
tools meet the library: every DVC stage runs ``python -m flows <stage>``, which
wraps one ``nnsf.stages`` function (files to files) in a Prefect flow and logs
the returned :class:`nnsf.pipeline.StageResult` to MLflow.

Modules:

- ``__main__``     the command line (``python -m flows …``);
- ``project``      where the project's files, stores and settings live;
- ``console``      what Prefect may print on the terminal (no tracebacks);
- ``mlflow_runs``  the MLflow store, experiment and run logging;
- ``stage_flows``  one flow per DVC stage (data … isomap);
- ``sweep``        the α/β/rank sweep: fan-out on a task runner, nested runs;
- ``runners``      the one place that chooses the sweep's task runner;
- ``prefect_server`` a short-lived local Prefect server for ``repro``;
- ``repro``        ``python -m flows repro``: ``dvc repro`` against that server;
- ``pipeline``     the scheduled flow (``dvc repro`` + a report) and its deployment.

Importing this package sets the telemetry switches of every tool to "off"
unless the user chose otherwise; it must happen before Prefect, MLflow or DVC
is imported, which is why it lives here and the package imports nothing heavy.
"""
from __future__ import annotations

import os

#: Telemetry off: these machines have no internet, and a pipeline should not
#: phone home anyway.  ``setdefault`` so an explicit user choice wins.
TELEMETRY_OFF = {
    "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
    "DO_NOT_TRACK": "1",
    "DVC_NO_ANALYTICS": "1",
    "MLFLOW_DISABLE_TELEMETRY": "true",
}

for _name, _value in TELEMETRY_OFF.items():
    os.environ.setdefault(_name, _value)
