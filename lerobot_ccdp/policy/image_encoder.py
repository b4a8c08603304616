"""Camera encoding: LeRobot's diffusion RGB encoder (crop, ResNet backbone, spatial softmax), reused as is.

One encoder shared by every camera, or one per camera (`use_separate_rgb_encoder_per_camera`), exactly as in
LeRobot's `DiffusionModel`, so a ccdp checkpoint encodes images the way a `diffusion` one does. One addition,
`vision_backbone_stages`: a ResNet divides the image size by 32 over its 4 stages, so a small camera image
(what a CPU can train on) leaves the spatial softmax a 2x2 or 1x1 map; keeping 3 stages keeps 4x4 at 64 px.
The features of one frame join its low-dimensional state, so they enter both the state condition of eps_s and
the history condition of eps_h (`BaseDenoiser`); the recovery head eps_z sees only z.
"""

import torch
from lerobot.policies.diffusion.modeling_diffusion import DiffusionRgbEncoder, SpatialSoftmax
from lerobot.policies.utils import get_output_shape
from torch import Tensor, nn

from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig


class ImageEncoder(nn.Module):
    """Images of every camera (..., C, H, W), normalised, -> one feature vector
    (..., n_cameras * 2 * keypoints)."""

    def __init__(self, config: CCDPConfig):
        super().__init__()
        self.keys = list(config.image_features)
        if config.use_separate_rgb_encoder_per_camera:
            self.rgb_encoder = nn.ModuleList(rgb_encoder(config) for _ in self.keys)
        else:
            self.rgb_encoder = rgb_encoder(config)

    def forward(self, images: list[Tensor]) -> Tensor:
        """`images`: one tensor per camera, in `self.keys` order, all of shape (*lead, C, H, W)."""
        lead = images[0].shape[:-3]
        flat = [image.reshape(-1, *image.shape[-3:]) for image in images]
        if isinstance(self.rgb_encoder, nn.ModuleList):
            features = [encoder(x) for encoder, x in zip(self.rgb_encoder, flat, strict=True)]
        else:  # one call for all cameras, as LeRobot batches them
            features = self.rgb_encoder(torch.cat(flat)).split(flat[0].shape[0])
        return torch.cat(features, dim=-1).reshape(*lead, -1)


def rgb_encoder(config: CCDPConfig) -> DiffusionRgbEncoder:
    """LeRobot's RGB encoder, its backbone cut after `config.vision_backbone_stages` ResNet stages."""
    encoder = DiffusionRgbEncoder(config)
    dropped = 4 - config.vision_backbone_stages
    if dropped:
        encoder.backbone = encoder.backbone[:-dropped]
    image_shape = next(iter(config.image_features.values())).shape
    encoded_size = config.crop_shape or config.resize_shape or image_shape[1:]
    feature_map = get_output_shape(encoder.backbone, (1, image_shape[0], *encoded_size))[1:]
    if feature_map[1] * feature_map[2] < 2:
        raise ValueError(
            f"Camera images of {tuple(encoded_size)} pixels leave the spatial softmax a "
            f"{feature_map[1]}x{feature_map[2]} feature map after {config.vision_backbone_stages} ResNet "
            "stages: every image would encode to the same keypoints. Use larger images (or "
            "--policy.resize_shape), or keep fewer stages (--policy.vision_backbone_stages=3 or 2)."
        )
    if dropped:
        encoder.pool = SpatialSoftmax(feature_map, num_kp=config.spatial_softmax_num_keypoints)
    return encoder
