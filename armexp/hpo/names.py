"""The samplers and pruners an HPO may name (`armexp.hpo.study` builds them); here, without
imports, so the config schema can check the names."""

SAMPLER_NAMES = ("tpe", "random", "cmaes", "qmc", "gp")
PRUNER_NAMES = ("median", "hyperband", "none")
