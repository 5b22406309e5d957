"""The networks every model is made of: MLPs, their ensemble layers (a member axis on the weights) and their closed
forms (``MLPTape``: pullback, push and curvature without autograd). The physical parts built of them live in
``encons.models.parts``."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Callable, cast

import torch
from torch import Tensor, nn

from encons.infra.batching import member_view, product
from encons.infra.errors import ConfigError

ACTIVATIONS = {"softplus": nn.Softplus, "tanh": nn.Tanh, "relu": nn.ReLU, "silu": nn.SiLU}


def mlp(
    in_dim: int, out_dim: int, hidden: int = 256, depth: int = 3, activation: str = "softplus", out_bias: bool = True
) -> nn.Sequential:
    """``depth`` hidden layers of width ``hidden`` (Zhong et al. §4.1: 3 × 256, Softplus).

    ``out_bias=False`` for a network that reaches the loss only through its derivatives (an energy H, L or
    V; a one-form): a constant there has no effect, so its bias never gets a gradient, which DDP refuses
    ("parameters that were not used in producing the loss"). The bias is still drawn, then dropped, so
    every other initial weight equals that of the network with it (same seed, same weights)."""
    if activation not in ACTIVATIONS:
        raise ConfigError(f"model.activation={activation!r} is unknown; allowed: {', '.join(sorted(ACTIVATIONS))}")
    layers: list[nn.Module] = []
    width = in_dim
    for _ in range(depth):
        layers += [nn.Linear(width, hidden), ACTIVATIONS[activation]()]
        width = hidden
    last = nn.Linear(width, out_dim)
    if not out_bias:
        last.register_parameter("bias", None)  # what nn.Linear(bias=False) holds
    layers.append(last)
    return nn.Sequential(*layers)


def cranmer_init_(
    net: nn.Sequential,
    generator: torch.Generator | None = None,
    convex: bool = False,
    potential_inputs: int = 0,
    input_rms: Tensor | None = None,
) -> nn.Sequential:
    """Cranmer et al. 2020 (LNN, appendix "Optimal initialization") in place: zero biases, weights
    N(0, σ²) with σ = s/√w, w the larger side of the layer, s = 2.2 (first layer), 0.58·i (hidden
    layer i), w (output layer). Found for softplus MLPs L(q, q̇) so that the Euler–Lagrange q̈,
    which needs (∇²_q̇ L)⁻¹, starts O(1); the default init makes ∇²_q̇ L near-singular.

    ``convex=True`` draws every weight after the first layer as |N(0, σ²)|, the same scales: with a
    convex non-decreasing activation (softplus) the network starts convex in its inputs (an
    input-convex network, Amos et al. 2017), so ∇²_q̇ L starts positive semi-definite everywhere instead
    of indefinite on most states.

    ``potential_inputs=k`` (> 0) keeps the first k inputs (q or its embedding) and the others (q̇) apart: the
    first half of every hidden layer sees only the former, the second half only the latter (the weights
    between them start at 0), and the output weights of the first half are negated. With ``convex`` the
    network starts as L = g(q̇) − h(q), g and h convex: the shape T − V of a mechanical Lagrangian, whose
    fresh dynamics q̈ = −(∇²g)⁻¹∇h oscillate about the minimum of h, where a jointly convex L (−L concave in
    q) pushes every state away from its minimum. Only the start: training may leave convexity and
    separability (the zero weights get gradients).

    ``input_rms`` (the inputs' typical sizes, (in,)): a first-layer column whose share of a pre-activation,
    of standard deviation σ·rms, would exceed 2 is scaled down to 2, so no input alone drives its units into
    softplus's flat tails (curvature σ(z)(1 − σ(z)) < 0.105 for |z| > 2, peak 0.25); a no-op for rms ≤ 0.9√w.
    """
    linears = [layer for layer in net if isinstance(layer, nn.Linear)]
    with torch.no_grad():
        for i, layer in enumerate(linears):
            width = max(layer.weight.shape)
            scale = 2.2 if i == 0 else width if i == len(linears) - 1 else 0.58 * i
            layer.weight.normal_(0.0, scale / width**0.5, generator=generator)
            if convex and i > 0:
                layer.weight.abs_()
            if layer.bias is not None:
                layer.bias.zero_()
            if i == 0 and input_rms is not None:
                layer.weight.div_((scale / width**0.5 * input_rms.to(layer.weight) / 2).clamp(min=1))
            if potential_inputs:
                rows, cols = layer.weight.shape
                potential_cols = torch.arange(cols) < (potential_inputs if i == 0 else cols // 2)
                if i < len(linears) - 1:  # rows of the first half see the potential's columns only
                    layer.weight.mul_((torch.arange(rows) < rows // 2)[:, None] == potential_cols[None, :])
                else:
                    layer.weight.mul_(1 - 2 * potential_cols.to(layer.weight))
    return net


def _sigmoid_slopes(z: Tensor) -> tuple[Tensor, Callable[[], Tensor]]:
    s = torch.sigmoid(z)
    return s, lambda: s * (1 - s)


def _tanh_slopes(z: Tensor) -> tuple[Tensor, Callable[[], Tensor]]:
    slope = 1 - torch.tanh(z).square()
    return slope, lambda: -2 * torch.tanh(z) * slope


def _relu_slopes(z: Tensor) -> tuple[Tensor, Callable[[], Tensor]]:
    return (z > 0).to(z), lambda: torch.zeros_like(z)


def _silu_slopes(z: Tensor) -> tuple[Tensor, Callable[[], Tensor]]:
    s = torch.sigmoid(z)
    return s * (1 + z * (1 - s)), lambda: s * (1 - s) * (2 + z * (1 - 2 * s))


# σ'(z) and, on demand, σ''(z) of each activation in ACTIVATIONS (softplus: σ' is the logistic sigmoid)
SLOPES: dict[type, Callable[[Tensor], tuple[Tensor, Callable[[], Tensor]]]] = {
    nn.Softplus: _sigmoid_slopes,
    nn.Tanh: _tanh_slopes,
    nn.ReLU: _relu_slopes,
    nn.SiLU: _silu_slopes,
}


def _narrow(width: int) -> bool:
    """Whether a product whose output is ``width`` columns wide (of ≥ 16 rows) is computed transposed:
    MKL on CPU (torch 2.13) ran outputs of 2–15 columns slower than their transposes, and those of 1 or
    ≥ 16 columns as fast or faster directly (``benchmarks/speed.py`` measures the models that use it).
    """
    return 1 < width < 16


class EnsembleLinear(nn.Module):
    """K ``nn.Linear`` layers as one: ``weight`` (K, out, in) and ``bias`` (K, out) (or None), on inputs whose
    leading axis is the member axis, (K, ..., in) -> (K, ..., out), or the member axis folded member-major into
    it, (K·N, ..., in) -> (K·N, ..., out) (rows k·N … (k+1)·N − 1 are member k's: the same memory), by one
    batched product (the ensemble dimension written into the layer; ``encons.training.stacked`` builds seed
    ensembles of them). ``MLPTape`` and ``narrow_in``/``narrow_out`` read these weights per member too.

    The parameter is ``weight_t``, Wᵀ (K, in, out) row-major, and ``weight`` its transposed view: the product
    x Wᵀ then reads it as stored, and ``bmm``'s backward, which gives its second operand's gradient as
    xᵀ ḡ (K, in, out) row-major whatever that operand's layout, gives it in the parameter's own layout. With a
    (K, out, in) parameter autograd copied that gradient into the parameter's layout at every step (K·out·in
    numbers per layer; the 2-D ``mm`` of one ``nn.Linear`` has a layout-aware backward and does not), and a
    transposed-strided parameter sends the fused AdamW through a copy instead (it takes contiguous tensors)."""

    def __init__(self, layers: Sequence[nn.Linear]):
        super().__init__()
        self.weight_t = nn.Parameter(torch.stack([layer.weight.detach().T for layer in layers]).contiguous())
        self.bias = (
            None
            if layers[0].bias is None
            else nn.Parameter(torch.stack([layer.bias.detach() for layer in layers]).contiguous())
        )

    @property
    def weight(self) -> Tensor:
        """The members' weights (K, out, in): a view of ``weight_t``."""
        return self.weight_t.transpose(1, 2)

    def member_parameters(self) -> dict[str, Tensor]:
        """The stacked tensors under the members' own parameter names (``encons.training.stacked.copy_members``)."""
        return {"weight": self.weight} | ({} if self.bias is None else {"bias": self.bias})

    def forward(self, x: Tensor) -> Tensor:
        rows = x.reshape(self.weight_t.shape[0], -1, x.shape[-1])
        out = (
            torch.bmm(rows, self.weight_t)
            if self.bias is None
            else torch.baddbmm(self.bias.unsqueeze(1), rows, self.weight_t)
        )
        return out.reshape(*x.shape[:-1], out.shape[-1])


#: The layers ``MLPTape`` reads as linear: a network's own, and K of them stacked
LINEAR = (nn.Linear, EnsembleLinear)


def narrow_in(x: Tensor, weight_t: Tensor, bias: Tensor | None = None) -> Tensor:
    """x @ Wᵀ (+ b) for x (..., d) and Wᵀ (d, width) given row-major (a network's first layer, or
    an output cotangent pulled back through its last); member-stacked Wᵀ (K, d, width) and b (K, width) act per
    member on x (K, ..., d) (``product``).

    For a ``_narrow`` d, x goes in column-major: torch's mm backward returns each operand's gradient in
    that operand's layout (``mm_mat1_backward``/``mm_mat2_backward``), so x̄ = (W ḡᵀ)ᵀ and
    W̄ᵀ = xᵀ ḡ both come out (d, ·) wide, not (·, d) narrow. Same values as ``x @ weight_t``.
    """
    if weight_t.dim() == 3:
        out = product(x, weight_t)
        return out if bias is None else out + member_view(bias, out.dim())
    if not _narrow(x.shape[-1]):
        return x @ weight_t if bias is None else torch.nn.functional.linear(x, weight_t.T, bias)
    rows = x.reshape(-1, x.shape[-1]).T.contiguous().T
    out = rows @ weight_t if bias is None else torch.addmm(bias, rows, weight_t)
    return out.reshape(*x.shape[:-1], weight_t.shape[-1])


def narrow_out(g: Tensor, weight_t: Tensor, bias: Tensor | None = None) -> Tensor:
    """g @ W (+ b) (..., d) for g (..., width) and Wᵀ (d, width) row-major, as (Wᵀ gᵀ + b)ᵀ for a
    ``_narrow`` d (a first layer's input gradient, or a last layer of a few outputs: W_L is its own
    row-major Wᵀ); its own backward products come out wide, see ``narrow_in``. Member-stacked as ``narrow_in``."""
    if weight_t.dim() == 3:
        out = product(g, weight_t.transpose(-1, -2))
        return out if bias is None else out + member_view(bias, out.dim())
    if not _narrow(weight_t.shape[0]):
        return g @ weight_t.T if bias is None else torch.nn.functional.linear(g, weight_t, bias)
    rows = g.reshape(-1, g.shape[-1]).T
    out = weight_t @ rows if bias is None else torch.addmm(bias.unsqueeze(-1), weight_t, rows)
    return out.T.reshape(*g.shape[:-1], weight_t.shape[0])


def run(net: nn.Sequential, x: Tensor) -> Tensor:
    """net(x) for an ``mlp``, its first layer through ``narrow_in`` and its last through ``narrow_out``
    (same values to rounding)."""
    first, *hidden, last = net
    weight, bias = _weight_bias(first)
    a = narrow_in(x, weight.transpose(-1, -2).contiguous(), bias)
    for layer in hidden:
        a = layer(a)
    return narrow_out(a, *_weight_bias(last))


def _weight_bias(layer: nn.Module) -> tuple[Tensor, Tensor | None]:
    """The weight and bias (None: dropped) of one of an ``mlp``'s ``nn.Linear`` layers, typed (``nn.Module``'s
    attribute access is not)."""
    return cast(Tensor, layer.weight), cast("Tensor | None", layer.bias)


class MLPTape:
    """One forward pass of an ``mlp`` at inputs x (..., d) that keeps what its input derivatives need,
    so that they follow in closed form: the chain rule written out through the Linear layers and the
    elementwise activations (z_k = W_k a_{k−1} + b_k, a_k = σ(z_k)), as plain tensor operations.

    Against ``torch.func``/``autograd.grad`` on the same network this builds no derivative graph of
    the activation's own backward (a training step differentiates σ' = sigmoid, not softplus'
    backward) and, for second derivatives, uses that Linear layers have none: for a scalar output,
    uᵀ ∇²f v = Σ_k Σ_j ḡ_kj σ''(z_kj) ż_kj(u) ż_kj(v) with ḡ_k = ∂f/∂a_k from ``pullback`` and ż_k
    the forward tangents from ``push``, so a Hessian block costs one forward tangent per direction
    instead of a Hessian-vector product (reverse over reverse). Values equal autodiff's to rounding.
    Member-stacked layers (``encons.training.stacked.EnsembleLinear``: weights (K, out, in)) act per member on inputs
    whose leading axis is the member axis: one batched product per layer for all members.
    """

    def __init__(self, net: nn.Sequential, x: Tensor):
        self.linears = [layer for layer in net if isinstance(layer, LINEAR)]
        self.first = self.linears[0].weight.transpose(-1, -2).contiguous()  # W_1ᵀ (d, width), row-major
        self.slopes: list[tuple[Tensor, Callable[[], Tensor]]] = []
        self.adjoints: list[Tensor] = []
        a = x
        for linear, activation in zip(self.linears, (layer for layer in net if not isinstance(layer, LINEAR))):
            z = narrow_in(a, self.first, linear.bias) if linear is self.linears[0] else linear(a)
            a = activation(z)
            self.slopes.append(SLOPES[type(activation)](z))
        self.out = narrow_out(a, self.linears[-1].weight, self.linears[-1].bias)

    def pullback(self, cotangent: Tensor | None = None) -> Tensor:
        """cᵀ ∂out/∂x (..., d) for output cotangents c (..., out), or ∇out for a scalar output (no c:
        the last layer's weight row, no product); keeps ḡ_k = cᵀ ∂out/∂a_k."""
        last = self.linears[-1].weight
        g = (
            (last if last.dim() == 2 else member_view(last, self.out.dim()))
            if cotangent is None
            else narrow_in(cotangent, last)
        )
        self.adjoints = []
        for linear, (slope, _) in zip(reversed(self.linears[1:-1]), reversed(self.slopes[1:])):
            self.adjoints.insert(0, g)
            g = product(g * slope, linear.weight)
        self.adjoints.insert(0, g)
        return narrow_out(g * self.slopes[0][0], self.first)

    def push(self, tangent: Tensor) -> tuple[Tensor, list[Tensor]]:
        """∂out/∂x · t (..., k, out) and the pre-activation tangents ż_k (..., k, ·), for k input
        tangents t (..., k, d) per sample (directions second to last: every product stays one matmul)."""
        tangents = self.hidden_tangents(narrow_in(tangent, self.first))
        return narrow_out(self.slopes[-1][0].unsqueeze(-2) * tangents[-1], self.linears[-1].weight), tangents

    def hidden_tangents(self, first: Tensor) -> list[Tensor]:
        """The pre-activation tangents ż_k of ``push`` alone (what ``curvature`` needs, not the output's),
        from the first layer's ż_1 = W_1 t (..., k, width): a caller may have them without the product
        (e.g. columns of W_1 for unit directions t)."""
        tangents = [first]
        for linear, (slope, _) in zip(self.linears[1:-1], self.slopes):
            tangents.append(product(slope.unsqueeze(-2) * tangents[-1], linear.weight.transpose(-1, -2)))
        return tangents

    def curvature(self, tangents: list[Tensor], rows: int | None = None) -> Tensor:
        """uᵢᵀ ∇²(cᵀ out) u_j (..., I, J) for the tangents ż_k of J directions u (..., J, ·) from ``push``
        or ``hidden_tangents``, i < I = ``rows`` (all J by default), c the cotangent of the last
        ``pullback``: Σ_k ż_k,i ⊙ (ḡ_k ⊙ σ''(z_k)) · ż_k,j (``layer_curvature``)."""
        weights = [adjoint * second() for adjoint, (_, second) in zip(self.adjoints, self.slopes)]
        return layer_curvature(tangents[-1].shape[-2] if rows is None else rows, tangents, weights)


def _layer_curvature(rows: int, tangents: list[Tensor], weights: list[Tensor]) -> Tensor:
    # a Tensor, not sum's start 0: an mlp has at least one layer, so there is at least one tangent
    return cast(
        Tensor, sum((t[..., :rows, :] * w.unsqueeze(-2)) @ t.transpose(-1, -2) for t, w in zip(tangents, weights))
    )


class LayerCurvature(torch.autograd.Function):
    """S = Σ_k (T_k[:I] ⊙ w_k) T_kᵀ (..., I, J) of tangents T_k (..., J, C) and weights w_k (..., C):
    the same values and derivatives as the plain expression, faster to train through.

    Hand-written only for speed: autograd of the plain expression runs per layer two small
    batched products (one in the orientation MKL runs slowest on CPU, ``_narrow``), a slice's backward and
    a sum for the rows shared with the columns; this backward runs one product per layer:
    P_k = (Ḡ⁺ + Ḡ⁺ᵀ) T_k with Ḡ⁺ the cotangent padded to (J, J), T̄_k = P_k ⊙ w_k,
    w̄_k = ½ Σ_j T_k,j ⊙ P_k,j. Double backward, ``vmap`` and ``jvp`` follow from torch ops.
    """

    generate_vmap_rule = True

    @staticmethod
    def forward(rows: int, *args: Tensor) -> Tensor:
        return _layer_curvature(rows, list(args[: len(args) // 2]), list(args[len(args) // 2 :]))

    @staticmethod
    def setup_context(ctx, inputs, output) -> None:
        ctx.rows = inputs[0]
        ctx.save_for_backward(*inputs[1:])
        ctx.save_for_forward(*inputs[1:])

    @staticmethod
    def backward(ctx, grad: Tensor) -> tuple[Tensor | None, ...]:
        saved = ctx.saved_tensors
        tangents, weights = saved[: len(saved) // 2], saved[len(saved) // 2 :]
        padded = nn.functional.pad(grad, (0, 0, 0, grad.shape[-1] - ctx.rows))
        symmetric = padded + padded.transpose(-1, -2)
        products = [symmetric @ t for t in tangents]
        return (
            None,
            *(p * w.unsqueeze(-2) for p, w in zip(products, weights)),
            *(0.5 * (p * t).sum(-2) for p, t in zip(products, tangents)),
        )

    @staticmethod
    def jvp(ctx, rows_dot: None, *dots: Tensor | None) -> Tensor:
        saved = ctx.saved_tensors
        half = len(saved) // 2
        total: Tensor | int = 0
        for t, w, t_dot, w_dot in zip(saved[:half], saved[half:], dots[:half], dots[half:]):
            if t_dot is not None:
                total = total + (t_dot[..., : ctx.rows, :] * w.unsqueeze(-2)) @ t.transpose(-1, -2)
                total = total + (t[..., : ctx.rows, :] * w.unsqueeze(-2)) @ t_dot.transpose(-1, -2)
            if w_dot is not None:
                total = total + (t[..., : ctx.rows, :] * w_dot.unsqueeze(-2)) @ t.transpose(-1, -2)
        return cast(Tensor, total)  # torch calls jvp only when some input has a tangent: a Tensor


def layer_curvature(rows: int, tangents: list[Tensor], weights: list[Tensor]) -> Tensor:
    """Σ_k (T_k[..., :rows, :] ⊙ w_k) T_kᵀ (..., rows, J) for tangents T_k (..., J, C) and weights
    w_k (..., C) (``LayerCurvature``; under ``torch.compile`` the plain expression)."""
    if torch.compiler.is_compiling():
        return _layer_curvature(rows, tangents, weights)
    return LayerCurvature.apply(rows, *tangents, *weights)
