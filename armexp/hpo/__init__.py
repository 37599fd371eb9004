"""Hyperparameter search with Optuna: the search space (`space`), the study and its storage
(`study`), the trials' MLflow runs (`record`), pruning (`pruning`), `armexp hpo`'s loop
(`search`) and the Optuna sweeper's preparation (`sweep`)."""
