"""Small CPU batches of LeRobot's diffusion UNet on ATen's own convolution kernel instead of oneDNN's.

On CPU, oneDNN's 1-D convolution is slower than ATen's for this UNet at 2-4 rows with more than one thread
(lerobot_ccdp.benchmark.policy_cost); composed sampling runs exactly such small batches, one row per score
term. `torch.backends.mkldnn.flags(enabled=False)` would select ATen's kernel, but it sets a process-wide flag
(ATen's global context, not thread-local): other threads' convolutions lose oneDNN meanwhile, and two threads
saving and restoring it can leave it off for good. So the choice is made per call, inside the convolution
modules: they call the 2-D kernel that convolution itself uses for a 1-D input with oneDNN off (same results,
bit for bit).
"""

import torch
from torch import Tensor, nn

# The kernels are private to torch: where a torch lacks them, the network keeps its plain convolutions.
ATEN_KERNELS = all(hasattr(torch._C._nn, name) for name in ("thnn_conv2d", "slow_conv_transpose2d"))


def _small_batch(x: Tensor) -> bool:
    """The batches that take ATen's kernel: 2-4 rows on CPU."""
    return x.is_cpu and 1 < x.shape[0] <= 4


class _SmallBatchConv1d(nn.Conv1d):
    """nn.Conv1d that runs small CPU batches on ATen's kernel. Its arguments are kept in 2-D form (`_args_2d`,
    set by `with_small_batch_convolutions`): Python work per call would otherwise eat the gain."""

    def _conv_forward(self, input: Tensor, weight: Tensor, bias: Tensor | None) -> Tensor:
        if not _small_batch(input):
            return super()._conv_forward(input, weight, bias)
        kernel, stride, padding = self._args_2d
        return torch._C._nn.thnn_conv2d(
            input.contiguous().unsqueeze(2), weight.unsqueeze(2), kernel, bias, stride, padding
        ).squeeze(2)


class _SmallBatchConvTranspose1d(nn.ConvTranspose1d):
    """nn.ConvTranspose1d counterpart of `_SmallBatchConv1d` (the UNet's upsampling layers)."""

    def forward(self, input: Tensor, output_size: list[int] | None = None) -> Tensor:
        if output_size is not None or not _small_batch(input):
            return super().forward(input, output_size)
        kernel, stride, padding, output_padding, dilation = self._args_2d
        return torch._C._nn.slow_conv_transpose2d(
            input.contiguous().unsqueeze(2),
            self.weight.unsqueeze(2),
            kernel,
            self.bias,
            stride,
            padding,
            output_padding,
            dilation,
        ).squeeze(2)


def with_small_batch_convolutions(network: nn.Module) -> nn.Module:
    """Turn a network's plain 1-D convolutions (zero padding given as numbers, one group, no dilation) into
    the small-batch classes above, in place; parameters and state dict are unchanged."""
    if not ATEN_KERNELS:
        return network
    for module in network.modules():
        if (
            type(module) not in (nn.Conv1d, nn.ConvTranspose1d)
            or isinstance(module.padding, str)
            or (module.padding_mode, module.groups, module.dilation) != ("zeros", 1, (1,))
        ):
            continue
        kernel, stride, padding = [1, *module.kernel_size], [1, *module.stride], [0, *module.padding]
        if type(module) is nn.Conv1d:
            module.__class__, module._args_2d = _SmallBatchConv1d, (kernel, stride, padding)
        else:
            module.__class__ = _SmallBatchConvTranspose1d
            module._args_2d = (kernel, stride, padding, [0, *module.output_padding], [1, 1])
    return network
