"""Pipeline stages: thin functions ``run(cfg)``, config in → MLflow run out."""
