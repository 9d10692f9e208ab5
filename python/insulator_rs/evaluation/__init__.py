"""Studies that reproduce and extend the paper's results (localization error, flight time)."""
