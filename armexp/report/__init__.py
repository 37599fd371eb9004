"""Tables and figures computed from MLflow data alone (pandas, matplotlib; no simulation)."""
