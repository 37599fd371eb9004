"""armexp's Hydra sweeper plugins (Hydra loads sweepers only from the ``hydra_plugins``
namespace); see `hydra_plugins.armexp_sweeper.optuna_sweeper`."""
