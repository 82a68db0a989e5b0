"""Training, evaluation (the paper's Table 2) and export of the nominal NARX model."""
