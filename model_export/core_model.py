"""Task-agnostic Encode-Process-Decode graph network (MeshGraphNets style).

Encoder and Messenger MLPs with two hidden layers (latent 128 by default), a
configurable number of message-passing steps with residual updates of node and
edge latents, density-weighted message aggregation, and a per-node Decoder.
Only ONNX-friendly operations (gather, scatter_add, matmul, layer norm).
"""

from __future__ import annotations

import torch
from torch import nn


def mlp(in_size: int, latent: int, out_size: int, *, layer_norm: bool = True) -> nn.Sequential:
    """Two hidden ReLU layers of ``latent`` units, then a linear output (and LayerNorm)."""
    layers: list[nn.Module] = [
        nn.Linear(in_size, latent),
        nn.ReLU(),
        nn.Linear(latent, latent),
        nn.ReLU(),
        nn.Linear(latent, out_size),
    ]
    if layer_norm:
        layers.append(nn.LayerNorm(out_size))
    return nn.Sequential(*layers)


def scatter_sum(values: torch.Tensor, index: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """Sum rows of ``values`` into rows ``index`` of a zero tensor shaped like ``like``."""
    expanded = index.unsqueeze(1).expand(-1, values.shape[1])
    return torch.zeros_like(like).scatter_add(0, expanded, values)


class GraphNetBlock(nn.Module):
    """One message-passing step: edge (message) update, then node update, both residual.

    The messenger's first layer on ``[edge, receiver, sender]`` is split into an
    edge part and two node parts computed per node and gathered (same function,
    fewer multiplications). Messages reaching a node are averaged with the
    senders' weights (the density): ``sum_j w_j m_ji / sum_j w_j``.
    """

    def __init__(self, latent: int) -> None:
        super().__init__()
        self.edge_in = nn.Linear(latent, latent)
        self.receiver_in = nn.Linear(latent, latent, bias=False)
        self.sender_in = nn.Linear(latent, latent, bias=False)
        self.edge_rest = nn.Sequential(
            nn.ReLU(),
            nn.Linear(latent, latent),
            nn.ReLU(),
            nn.Linear(latent, latent),
            nn.LayerNorm(latent),
        )
        self.node_mlp = mlp(2 * latent, latent, latent)

    def forward(
        self,
        nodes: torch.Tensor,
        edges: torch.Tensor,
        senders: torch.Tensor,
        receivers: torch.Tensor,
        sender_weight: torch.Tensor,
        weight_total: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        hidden = (
            self.edge_in(edges)
            + self.receiver_in(nodes).index_select(0, receivers)
            + self.sender_in(nodes).index_select(0, senders)
        )
        messages = self.edge_rest(hidden)
        aggregated = scatter_sum(messages * sender_weight, receivers, nodes) / weight_total
        nodes = nodes + self.node_mlp(torch.cat([nodes, aggregated], dim=1))
        return nodes, edges + messages


class EncodeProcessDecode(nn.Module):
    """Encoder MLPs -> ``steps`` GraphNetBlocks -> per-node Decoder MLP."""

    def __init__(
        self, node_in: int, edge_in: int, out_size: int, *, latent: int = 128, steps: int = 6
    ) -> None:
        super().__init__()
        self.node_encoder = mlp(node_in, latent, latent)
        self.edge_encoder = mlp(edge_in, latent, latent)
        self.blocks = nn.ModuleList([GraphNetBlock(latent) for _ in range(steps)])
        self.decoder = mlp(latent, latent, out_size, layer_norm=False)

    def forward(
        self,
        node_features: torch.Tensor,
        edge_features: torch.Tensor,
        senders: torch.Tensor,
        receivers: torch.Tensor,
        node_weight: torch.Tensor,
    ) -> torch.Tensor:
        """Per-node outputs; ``node_weight`` (N,) scales the messages each node sends."""
        nodes = self.node_encoder(node_features)
        edges = self.edge_encoder(edge_features)
        sender_weight = node_weight.index_select(0, senders).unsqueeze(1)
        weight_total = scatter_sum(sender_weight, receivers, node_weight.unsqueeze(1))
        weight_total = weight_total + 1e-6
        for block in self.blocks:
            nodes, edges = block(nodes, edges, senders, receivers, sender_weight, weight_total)
        return self.decoder(nodes)
