"""PDNet: the learned mixer of Firmino, Frisvad & Jensen 2022 (docs/mixer_network.md).

Binding contract: docs/mixer_network.md.  Input channels (18, RGB groups):
  x, y, atan(var), atan(sure), atan((x-y)^2), atan(sure + var - (x-y)^2)
Output: raw [9] = a (0-2), b (3-5), c (6-8);  alpha = clip((a-b)/max(c,1e-6), 0, 1).
"""
import torch
import torch.nn as nn
import torch.nn.functional as F

IN_CHANNELS = 18
OUT_CHANNELS = 9
C_EPS = 1e-6


class ResBlock(nn.Module):
    def __init__(self, width):
        super().__init__()
        self.conv1 = nn.Conv2d(width, width, 3, padding=1)
        self.conv2 = nn.Conv2d(width, width, 3, padding=1)

    def forward(self, h):
        return F.relu(h + self.conv2(F.relu(self.conv1(h))))


class PDNet(nn.Module):
    def __init__(self, width=48):
        super().__init__()
        self.width = width
        self.conv_in = nn.Conv2d(IN_CHANNELS, width, 5, padding=2)
        self.res1 = ResBlock(width)
        self.res2 = ResBlock(width)
        self.conv_out = nn.Conv2d(width, OUT_CHANNELS, 3, padding=1)
        self.reset_output()

    @torch.no_grad()
    def reset_output(self):
        """Untrained net: alpha ~= 0.5 everywhere with a stable division.

        The output convolution's weights are scaled down so the biases dominate:
        a = 0.5, b = 0, c = 1  ->  alpha = 0.5 + small input-dependent perturbation.
        """
        self.conv_out.weight.mul_(0.1)
        self.conv_out.bias.zero_()
        self.conv_out.bias[0:3] = 0.5
        self.conv_out.bias[6:9] = 1.0

    def raw(self, inp):
        h = F.relu(self.conv_in(inp))
        h = self.res1(h)
        h = self.res2(h)
        return self.conv_out(h)

    def forward(self, inp):
        """inp: [N,18,H,W] -> (raw [N,9,H,W], alpha [N,3,H,W])."""
        r = self.raw(inp)
        return r, activation(r)


def activation(raw):
    a, b, c = raw[:, 0:3], raw[:, 3:6], raw[:, 6:9]
    return torch.clamp((a - b) / torch.clamp_min(c, C_EPS), 0.0, 1.0)


def make_inputs(x, y, var, sure):
    """x, y, var, sure: [N,3,H,W] (or [3,H,W]) float tensors -> [N,18,H,W] (or [18,H,W])."""
    cat_dim = x.dim() - 3
    d2 = (x - y) ** 2
    return torch.cat([x, y, torch.atan(var), torch.atan(sure), torch.atan(d2),
                      torch.atan(sure + var - d2)], dim=cat_dim)


def mix(x, y, alpha):
    return x + alpha * (y - x)


def width_from_state(state):
    return int(state["conv_in.weight"].shape[0])


def load_model(path, map_location="cpu"):
    obj = torch.load(path, map_location=map_location)
    state = obj["state_dict"] if isinstance(obj, dict) and "state_dict" in obj else obj
    net = PDNet(width_from_state(state))
    net.load_state_dict(state)
    net.eval()
    return net


TENSOR_NAMES = [
    "conv_in.weight", "conv_in.bias",
    "res1.conv1.weight", "res1.conv1.bias", "res1.conv2.weight", "res1.conv2.bias",
    "res2.conv1.weight", "res2.conv1.bias", "res2.conv2.weight", "res2.conv2.bias",
    "conv_out.weight", "conv_out.bias",
]


def expected_shapes(width):
    W = width
    return {
        "conv_in.weight": (W, 18, 5, 5), "conv_in.bias": (W,),
        "res1.conv1.weight": (W, W, 3, 3), "res1.conv1.bias": (W,),
        "res1.conv2.weight": (W, W, 3, 3), "res1.conv2.bias": (W,),
        "res2.conv1.weight": (W, W, 3, 3), "res2.conv1.bias": (W,),
        "res2.conv2.weight": (W, W, 3, 3), "res2.conv2.bias": (W,),
        "conv_out.weight": (9, W, 3, 3), "conv_out.bias": (9,),
    }


if __name__ == "__main__":
    torch.manual_seed(0)
    net = PDNet(48)
    print(list(net.state_dict().keys()))
    assert list(net.state_dict().keys()) == TENSOR_NAMES
    for k, v in net.state_dict().items():
        assert tuple(v.shape) == expected_shapes(48)[k], k
    x = torch.rand(1, 3, 20, 24)
    inp = make_inputs(x, x * 0.9, x * 0.01, x * 0.02 - 0.01)
    r, a = net(inp)
    print(inp.shape, r.shape, a.shape, float(a.mean()), float(a.min()), float(a.max()))
