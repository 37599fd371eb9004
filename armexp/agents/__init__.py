"""Building SB3 agents from config, their environments, and the bridges to MLflow."""
