"""The UNet's small CPU batches run on ATen's convolution per call, leaving the process-wide oneDNN switch
alone."""

import copy
import threading

import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.policies.diffusion.modeling_diffusion import DiffusionConditionalUnet1d

from lerobot_ccdp.policy.base_denoiser import BaseDenoiser
from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig

CONFIG = CCDPConfig(
    input_features={"observation.state": PolicyFeature(FeatureType.STATE, (2,))},
    output_features={"action": PolicyFeature(FeatureType.ACTION, (2,))},
    device="cpu",
    failure_feature="action",
    horizon=16,
    down_dims=(32, 64, 128),
    diffusion_step_embed_dim=32,
)


@pytest.fixture(scope="module")
def denoiser() -> BaseDenoiser:
    torch.manual_seed(0)
    return BaseDenoiser(CONFIG).eval()


def inputs(denoiser: BaseDenoiser, rows: int) -> tuple[torch.Tensor, ...]:
    generator = torch.Generator().manual_seed(rows)
    keep = torch.ones(rows, 1)
    return (
        torch.randn(rows, 16, 2, generator=generator),
        torch.full((rows,), 3),
        torch.randn(rows, denoiser.state_cond_dim, generator=generator),
        keep,
        torch.randn(rows, denoiser.history_cond_dim, generator=generator),
        keep,
    )


def test_small_batches_leave_the_onednn_switch_on_for_other_threads(denoiser):
    seen: list[bool] = []
    inside, read = threading.Event(), threading.Event()

    def watcher():
        inside.wait()
        seen.append(torch.backends.mkldnn.enabled)
        read.set()

    def hold_until_read(*_):  # runs in the middle of the UNet's call, on the calling thread
        inside.set()
        read.wait(timeout=10)

    conv = next(m for m in denoiser.unet.modules() if isinstance(m, torch.nn.Conv1d))
    handle = conv.register_forward_hook(hold_until_read)
    thread = threading.Thread(target=watcher)
    thread.start()
    try:
        with torch.no_grad():
            denoiser(*inputs(denoiser, 3))
    finally:
        handle.remove()
        thread.join()
    assert seen == [True] and torch.backends.mkldnn.enabled


@pytest.mark.parametrize("rows", [1, 2, 3, 4, 8])
def test_same_results_as_the_stock_unet(denoiser, rows):
    """Bit for bit what the stock UNet gives with oneDNN off (ATen's kernel) at 2-4 rows, and with it on
    otherwise; close to oneDNN's at every size."""
    stock = copy.deepcopy(denoiser)
    stock.unet = DiffusionConditionalUnet1d(
        CONFIG, global_cond_dim=denoiser.state_cond_dim + denoiser.history_cond_dim + 2
    )
    stock.unet.load_state_dict(denoiser.unet.state_dict())
    args = inputs(denoiser, rows)
    with torch.no_grad():
        ours, onednn = denoiser(*args), stock(*args)
        torch.backends.mkldnn.enabled = False
        try:
            aten = stock(*args)
        finally:
            torch.backends.mkldnn.enabled = True
    assert torch.equal(ours, aten if 1 < rows <= 4 else onednn)
    torch.testing.assert_close(ours, onednn, rtol=1e-5, atol=1e-5)
