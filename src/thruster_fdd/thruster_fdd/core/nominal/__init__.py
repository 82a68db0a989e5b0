"""The nominal model: a NARX of the healthy thruster, whose residuals feed diagnosis
(docs/nominal_model.md).

``spec`` (architectures, hyperparameters, scaling) and ``card``, ``runtime`` (the loaded model's
online step) and ``residuals`` (the residual stream) are what runs on the vehicle: numpy and
numba only. ``networks``, ``training``, ``export`` and ``evaluation`` need torch.
"""
