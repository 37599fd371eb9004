"""The MLflow layer: every module that reads or writes the tracking store, one job each.

Stages hand data to each other only through MLflow (docs/design.md §1); this package is how.
Import the module that does the job (``from armexp.tracking import stage_runs``); this file
re-exports nothing, so the import graph shows who depends on which job.

* `store`: where a config's store and artifacts are (`store.store_uri`), opening a store once
  and safely, retrying a busy SQLite store, passwords kept out of what armexp logs.
* `new_store`: a new SQLite store copied from an empty one kept per MLflow version.
* `anchor`: artifact locations that follow a SQLite store copied or moved to another folder.
* `remote`: a store across the network (server, database) held to ``tracking.timeout_s``.
* `stage_runs`: one run per stage execution (`stage_runs.stage_run`): the experiment, params,
  config, lineage and liveness tags, parent runs, a truthful end; runs left RUNNING closed.
* `artifacts`: folders, tables and metric series logged to a run; a run's artifact fetched.
* `lookup`: the upstream run a stage consumes, by id or the latest matching FINISHED run.
* `run_ids`: run ids as users type them (a unique prefix) resolved to full ids.
* `run_names`: run names that say what a run is (``train-sac_quick-s0``).
* `run_end`: how a run ends: status written on a signal, a full disk or a lost store.
* `liveness`: a live run told from one whose process died (heartbeat, process identity).
* `lineage`: what ran (git commit, dirty flag, package versions) as tags.
* `reuse`: which earlier run ``pipeline.reuse`` takes instead of running a stage again.
* `sweeps`: a multirun's jobs listed before any runs, and the run that groups them.
* `diff`: ``armexp diff``: what differs between two runs.
* `tags`: every tag name armexp writes or reads; the one module that spells an ``armexp.*`` key.
"""
