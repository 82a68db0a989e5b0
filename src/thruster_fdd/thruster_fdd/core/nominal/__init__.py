"""The nominal model on the vehicle: a NARX of the healthy thruster, whose residuals feed
diagnosis (docs/nominal_model.md).

``spec`` (architectures, hyperparameters, scaling), ``card``, ``runtime`` (the loaded model's
online step) and ``residuals`` (the residual stream): numpy and numba only.
"""
