"""The image encoders (base.py: the interface; factory.py: the configured one).

Importing this package marks ``triton`` unavailable unless something already imported it. The encoders import
torchvision (open_clip and the packaged EfficientNet both do), whose ``ops.roi_align`` imports ``torch._dynamo``,
which imports triton merely to learn whether it is installed: ~75 MB of RSS (libtriton.so and its Python side) in a
process that never compiles a kernel (the companion has no ``torch.compile``; triton only generates GPU kernels for
it). torch treats the missing package as "no triton", as on any machine without it.
"""

import sys

sys.modules.setdefault("triton", None)  # type: ignore[arg-type]  # None: "import triton" raises ImportError
