"""The ensemble MLP's forward-mode pass with a hand-written backward: the derivative loss's one
Jacobian-vector product J_n ż_n per minibatch (`models.EnsembleMLP.normalized_outputs_with_tangent`)."""
import torch


class TangentPropagation(torch.autograd.Function):
    """Forward-mode pass through the stacked MLP: (z_n, ż_n) -> (outputs, J_n ż_n), hand-written backward.

    Primal and tangent travel together layer by layer (h = x W + b, ḣ = ẋ W, then f(h), f'(h) ḣ);
    the backward pass returns parameter gradients only (inputs are data). Costs one extra GEMM per
    layer and direction, never a Jacobian.
    """

    @staticmethod
    def forward(ctx, activation, tangent_dim, inputs, input_tangents, *parameters):
        count = len(parameters) // 2
        weights, biases = parameters[:count], parameters[count:]
        x, xd = inputs, input_tangents
        layers = []
        for weight, bias in zip(weights[:-1], biases[:-1]):
            h = torch.baddbmm(bias, x, weight)
            hd = torch.bmm(xd, weight)
            y, yd, slope, curvature = activation.tangent(h, hd)
            layers.append((x, xd, slope, curvature))
            x, xd = y, yd
        out_weight = weights[-1]
        outputs = torch.baddbmm(biases[-1], x, out_weight)
        output_tangents = torch.bmm(xd, out_weight[..., :tangent_dim])
        ctx.save_for_backward(*weights)
        ctx.layers = layers
        ctx.last = (x, xd)
        ctx.tangent_dim = tangent_dim
        return outputs, output_tangents

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_outputs, grad_tangents):
        weights = ctx.saved_tensors
        k = ctx.tangent_dim
        x, xd = ctx.last
        if grad_outputs is None:
            grad_outputs = torch.zeros(x.shape[:2] + (weights[-1].shape[-1],), dtype=x.dtype, device=x.device)
        if grad_tangents is None:
            grad_tangents = torch.zeros(xd.shape[:2] + (k,), dtype=x.dtype, device=x.device)
        out_weight = weights[-1]
        grad_weight = torch.bmm(x.transpose(1, 2), grad_outputs)
        grad_weight[..., :k].baddbmm_(xd.transpose(1, 2), grad_tangents)
        weight_grads = [grad_weight]
        bias_grads = [grad_outputs.sum(1, keepdim=True)]
        gy = torch.bmm(grad_outputs, out_weight.transpose(1, 2))
        gyd = torch.bmm(grad_tangents, out_weight[..., :k].transpose(1, 2))
        for index in range(len(ctx.layers) - 1, -1, -1):
            x, xd, slope, curvature = ctx.layers[index]
            if curvature is None:
                gh = gy.mul_(slope)
            else:
                gh = torch.mul(gyd, curvature).addcmul_(gy, slope)
            ghd = gyd.mul_(slope)
            bias_grads.append(gh.sum(1, keepdim=True))
            weight_grads.append(torch.bmm(x.transpose(1, 2), gh).baddbmm_(xd.transpose(1, 2), ghd))
            if index > 0:
                weight_t = weights[index].transpose(1, 2)
                gy = torch.bmm(gh, weight_t)
                gyd = torch.bmm(ghd, weight_t)
        return (None, None, None, None, *reversed(weight_grads), *reversed(bias_grads))
