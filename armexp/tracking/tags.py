"""Every MLflow tag armexp writes or reads, by name: the one owner of the ``armexp.*`` keys (and
of MLflow's own that armexp reads). Modules import the name; no other module spells a key."""

from __future__ import annotations

# ------------------------------------------------------------------ every run
#: The stage that made a run (simulate, tune, train, eval, play, report, pipeline, sweep, hpo,
#: trial).
STAGE_TAG = "armexp.stage"
#: MLflow's own: the parent run of a nested run.
PARENT_TAG = "mlflow.parentRunId"
#: MLflow's own, on an experiment: its kind. The UIs that read it open a "Machine learning"
#: experiment on its runs table, not on the GenAI overview of traces, which armexp never logs.
KIND_TAG, KIND = "mlflow.experimentKind", "custom_model_development"
#: The failure's one sentence, on a FAILED run.
ERROR_TAG = "armexp.error"
#: Code lineage (`armexp.tracking.lineage`): the git commit, whether the tree was dirty, and the
#: installed versions (``armexp.version.<package>``).
COMMIT_TAG = "armexp.git_commit"
DIRTY_TAG = "armexp.git_dirty"
VERSION_TAG = "armexp.version."
#: Liveness (`armexp.tracking.liveness`): the running process and its last heartbeat.
HEARTBEAT_TAG = "armexp.heartbeat"
PROCESS_TAG = "armexp.process"
#: The digest of a stage's inputs (`armexp.reads`), which reuse matches.
INPUTS_TAG = "armexp.inputs_hash"
#: The artifact root a store was made with (`armexp.tracking.anchor`).
ANCHOR_TAG = "armexp.artifact_root"

# ------------------------------------------------------------------ sweeps
#: A job's sweep run, and the stage a sweep run groups.
SWEEP_TAG = "armexp.sweep"
SWEEP_STAGE_TAG = "armexp.sweep_stage"

# ------------------------------------------------------------------ tune
#: The criterion and horizon a tune run optimised (and the gains it gave, via its run).
CRITERION_TAG = "armexp.criterion"
HORIZON_TAG = "armexp.horizon"
#: The tuned gains that sit on a bound of the search box ("none" when none does).
GAINS_ON_BOUND_TAG = "armexp.gains_on_bound"

# ------------------------------------------------------------------ train
#: The tune run whose gains a train run used (eval: ``armexp.tune_run.<label>`` per label).
TUNE_RUN_TAG = "armexp.tune_run"
TUNE_RUN_PREFIX = TUNE_RUN_TAG + "."
#: The PID baseline's tune run on eval runs made before the labelled tags.
PID_TUNE_RUN_TAG = "armexp.pid_tune_run"
#: Where a train run's gains came from: ``tune`` or ``config``.
GAINS_SOURCE_TAG = "armexp.gains_source"
#: The agent config group option a policy was trained with (train and eval runs).
AGENT_PRESET_TAG = "armexp.agent_preset"
#: Its ``agent.algo`` (train and eval runs), and the preset's options that algorithm does not
#: read (train runs where there are any; `armexp.agents.factory.usage`).
AGENT_ALGO_TAG = "armexp.agent_algo"
AGENT_LEFT_OUT_TAG = "armexp.agent_left_out"
#: The preset's options that algorithm reads with a meaning of its own, ``key=meaning`` joined by
#: ``;`` (PPO's ``batch_size=minibatch size``), where there are any.
AGENT_MAPPED_TAG = "armexp.agent_mapped"
#: The step a resumed train run continued from, and why a train run stopped.
RESUMED_TAG = "armexp.resumed_from_step"
STOP_REASON_TAG = "armexp.stop_reason"

# ------------------------------------------------------------------ eval and play
#: The train run whose policy an eval or play run ran, and the adaptive gains' source.
TRAIN_RUN_TAG = "armexp.train_run"
ADAPTIVE_GAINS_TAG = "armexp.adaptive_gains"

# ------------------------------------------------------------------ pipeline, study, report
#: A pipeline's stage runs (``armexp.run.<step>``), the steps it reused (``armexp.reused.<step>``)
#: or resumed (``armexp.resumed.<step>``), and the step that failed.
RUN_PREFIX = "armexp.run."
REUSED_PREFIX = "armexp.reused."
RESUMED_PREFIX = "armexp.resumed."
FAILED_STAGE_TAG = "armexp.failed_stage"
#: A study's seeds, and those whose pipeline failed.
STUDY_TAG = "armexp.study"
FAILED_SEEDS_TAG = "armexp.failed_seeds"
#: The eval runs a report read.
REPORT_RUNS_TAG = "armexp.report_runs"

# ------------------------------------------------------------------ hyperparameter search
#: An HPO run (stage ``hpo``: `armexp hpo` or a train sweep under ``hydra/sweeper=optuna``):
#: its Optuna study's name and storage (password hidden), and whether its trials prune.
HPO_STUDY_TAG = "armexp.hpo.study"
HPO_STORAGE_TAG = "armexp.hpo.storage"
HPO_PRUNER_TAG = "armexp.hpo.pruner"
#: A trial run (stage ``trial``, a child of its HPO run): its number in the study and how it
#: ended (COMPLETE, PRUNED, FAIL).
TRIAL_NUMBER_TAG = "armexp.hpo.trial"
TRIAL_STATE_TAG = "armexp.hpo.state"
