"""The torch networks of the six regressors (training and export only; the runtime never imports
this module).
"""

from __future__ import annotations

import torch
from torch import nn

from thruster_fdd.core.nominal.spec import IqrScaler, ModelSpec


def deadband(command: torch.Tensor, width: torch.Tensor) -> torch.Tensor:
    """Soft-threshold deadband: 0 for ``|command| <= width``, ``command -+ width`` outside."""
    return command - torch.clamp(command, -width, width)


class LagNet(nn.Module):
    """Feed-forward regressor of lagged inputs (and outputs): MLP, MLP-TDD, NARX, NARX-deadband.

    ``forward(u_hist, y_hist)`` takes raw signals, oldest first: ``u_hist`` shape
    (B, input_lags, 2) (command, V), ``y_hist`` shape (B, output_lags, 2) (rpm, A), and returns
    the raw prediction of the next sample, shape (B, 2). The scaler is held as buffers, so an
    exported program is self-contained. ``forward_scaled`` works in scaled units (training).
    """

    def __init__(self, spec: ModelSpec, u_scaler: IqrScaler, y_scaler: IqrScaler) -> None:
        super().__init__()
        if spec.is_recurrent:
            raise ValueError("LagNet is for feed-forward architectures, not LSTM/GRU")
        self.spec = spec
        self.register_buffer("u_center", torch.tensor(u_scaler.center, dtype=torch.float32))
        self.register_buffer("u_scale", torch.tensor(u_scaler.scale, dtype=torch.float32))
        self.register_buffer("y_center", torch.tensor(y_scaler.center, dtype=torch.float32))
        self.register_buffer("y_scale", torch.tensor(y_scaler.scale, dtype=torch.float32))
        n_in = spec.n_regressors
        layers = []
        for h in spec.hidden:
            layers.append(nn.Linear(n_in, h))
            n_in = h
        self.hidden = nn.ModuleList(layers)
        self.out = nn.Linear(n_in, 2)
        self.linear = nn.Linear(spec.n_regressors, 2, bias=False)
        # Deadband width in raw command units (the T100's ESC: 25 us = 0.0625).
        self.deadband_width = nn.Parameter(torch.tensor(0.05), requires_grad=spec.has_deadband)

    def regressor(self, u_hist: torch.Tensor, y_hist: torch.Tensor) -> torch.Tensor:
        """Scaled, flattened regressor vector, shape (B, 2 * (input_lags + output_lags))."""
        if self.spec.has_deadband:
            cmd = deadband(u_hist[..., 0], self.deadband_width.abs())
            u_hist = torch.stack((cmd, u_hist[..., 1]), dim=-1)
        u = (u_hist - self.u_center) / self.u_scale
        parts = [u.flatten(1)]
        if self.spec.output_lags:
            y = (y_hist - self.y_center) / self.y_scale
            parts.append(y[..., self.spec.feedback_index].flatten(1))
        return torch.cat(parts, dim=1)

    def forward_scaled(self, x: torch.Tensor) -> torch.Tensor:
        """Scaled prediction from a scaled regressor ``x`` (B, n_regressors) -> (B, 2)."""
        z = x
        for layer in self.hidden:
            z = torch.tanh(layer(z))
        return self.out(z) + self.linear(x)

    def forward(self, u_hist: torch.Tensor, y_hist: torch.Tensor) -> torch.Tensor:
        """Raw prediction (B, 2) of rpm and current from raw histories (see class docstring)."""
        return self.forward_scaled(self.regressor(u_hist, y_hist)) * self.y_scale + self.y_center


class RecurrentNet(nn.Module):
    """LSTM or GRU over the input sequence; ``forward(u)`` with raw ``u`` shape (B, T, 2) returns
    the raw predictions (B, T, 2), where output ``t`` is the prediction of sample ``t + 1``."""

    def __init__(self, spec: ModelSpec, u_scaler: IqrScaler, y_scaler: IqrScaler) -> None:
        super().__init__()
        if not spec.is_recurrent:
            raise ValueError("RecurrentNet is for lstm / gru")
        self.spec = spec
        self.register_buffer("u_center", torch.tensor(u_scaler.center, dtype=torch.float32))
        self.register_buffer("u_scale", torch.tensor(u_scaler.scale, dtype=torch.float32))
        self.register_buffer("y_center", torch.tensor(y_scaler.center, dtype=torch.float32))
        self.register_buffer("y_scale", torch.tensor(y_scaler.scale, dtype=torch.float32))
        cell = nn.LSTM if spec.architecture == "lstm" else nn.GRU
        self.rnn = cell(2, spec.hidden[0], batch_first=True)
        self.out = nn.Linear(spec.hidden[0], 2)

    def forward_scaled(self, u_scaled: torch.Tensor) -> torch.Tensor:
        """Scaled predictions (B, T, 2) from scaled inputs (B, T, 2)."""
        h, _ = self.rnn(u_scaled)
        return self.out(h)

    def forward(self, u: torch.Tensor) -> torch.Tensor:
        """Raw predictions (B, T, 2) from raw inputs (B, T, 2)."""
        z = self.forward_scaled((u - self.u_center) / self.u_scale)
        return z * self.y_scale + self.y_center


def build_network(spec: ModelSpec, u_scaler: IqrScaler, y_scaler: IqrScaler) -> nn.Module:
    """The torch module of ``spec``: ``LagNet`` or ``RecurrentNet``."""
    if spec.is_recurrent:
        return RecurrentNet(spec, u_scaler, y_scaler)
    return LagNet(spec, u_scaler, y_scaler)
