"""Image-quality measures for the enhancers: full-reference PSNR/SSIM and no-reference UCIQE/UIQM.

Why here: the enhancement benchmark needs numbers that mean the same thing run after run, so every constant is
fixed and written down (docs/enhancement.md repeats them). All functions take BGR uint8 images, as the rest of
the project does, and are vectorised with NumPy/OpenCV.

- PSNR: ``10 log10(255^2 / MSE)``, infinite for identical images.
- SSIM (Wang, Bovik, Sheikh, Simoncelli 2004): 11x11 Gaussian window, sigma 1.5, K1 = 0.01, K2 = 0.03, L = 255,
  the SSIM map averaged over the pixels whose whole window lies inside the image ("valid"), then over channels.
- UCIQE (Yang & Sowmya 2015): ``0.4680 sigma_c + 0.2745 con_l + 0.2576 mu_s`` in CIE L*a*b*, with chroma
  ``C = sqrt(a*^2 + b*^2) / 100``, ``sigma_c`` its standard deviation, ``con_l`` the mean of the top 1% minus the
  mean of the bottom 1% of ``L*/100``, and ``mu_s`` the mean saturation ``C* / sqrt(C*^2 + L*^2)``.
- UIQM (Panetta, Gao, Agaian 2016): ``0.0282 UICM + 0.2953 UISM + 3.5753 UIConM``; see the functions below.
"""

from __future__ import annotations

import cv2
import numpy as np

SSIM_K1 = 0.01
SSIM_K2 = 0.03
SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
UCIQE_C = (0.4680, 0.2745, 0.2576)
UIQM_C = (0.0282, 0.2953, 3.5753)
UIQM_BLOCK = 8
"""Side of the square blocks the EME and AMEE measures of UIQM are taken over."""
UICM_TRIM = 0.1
"""Share trimmed from each end for the alpha-trimmed mean of UICM (alpha_L = alpha_R = 0.1 in the paper)."""
PLIP_GAMMA = 1026.0
"""PLIP constants gamma = k = lambda = 1026 (Panetta et al.)."""


def _check_pair(a: np.ndarray, b: np.ndarray) -> None:
    if a.shape != b.shape:
        raise ValueError(f"images differ in shape: {a.shape} vs {b.shape}")


def psnr(image: np.ndarray, reference: np.ndarray) -> float:
    """Peak signal-to-noise ratio in dB for 8-bit images; ``inf`` when they are identical."""
    _check_pair(image, reference)
    mse = float(np.mean((image.astype(np.float64) - reference.astype(np.float64)) ** 2))
    if mse == 0.0:
        return float("inf")
    return 10.0 * np.log10(255.0**2 / mse)


def _ssim_channel(x: np.ndarray, y: np.ndarray) -> float:
    c1 = (SSIM_K1 * 255.0) ** 2
    c2 = (SSIM_K2 * 255.0) ** 2
    k = (SSIM_WINDOW, SSIM_WINDOW)

    def blur(img: np.ndarray) -> np.ndarray:
        return cv2.GaussianBlur(img, k, SSIM_SIGMA, borderType=cv2.BORDER_REFLECT)

    mu_x, mu_y = blur(x), blur(y)
    var_x = blur(x * x) - mu_x * mu_x
    var_y = blur(y * y) - mu_y * mu_y
    cov = blur(x * y) - mu_x * mu_y
    ssim_map = ((2 * mu_x * mu_y + c1) * (2 * cov + c2)) / ((mu_x**2 + mu_y**2 + c1) * (var_x + var_y + c2))
    r = SSIM_WINDOW // 2
    if ssim_map.shape[0] > 2 * r and ssim_map.shape[1] > 2 * r:
        ssim_map = ssim_map[r:-r, r:-r]
    return float(ssim_map.mean())


def ssim(image: np.ndarray, reference: np.ndarray) -> float:
    """Structural similarity in [-1, 1] (1: identical), the mean over colour channels."""
    _check_pair(image, reference)
    x = image.astype(np.float64)
    y = reference.astype(np.float64)
    if x.ndim == 2:
        return _ssim_channel(x, y)
    return float(np.mean([_ssim_channel(x[..., c], y[..., c]) for c in range(x.shape[2])]))


def _lab(image: np.ndarray) -> np.ndarray:
    """CIE L*a*b* with L* in [0, 100] and a*, b* in about [-128, 127] (float input keeps the true scale)."""
    return cv2.cvtColor(image.astype(np.float32) / 255.0, cv2.COLOR_BGR2LAB).astype(np.float64)


def uciqe(image: np.ndarray) -> float:
    """Underwater colour image quality evaluation (higher: more colourful and contrasted); see the module doc."""
    lab = _lab(image)
    lum, a, b = lab[..., 0], lab[..., 1], lab[..., 2]
    chroma_raw = np.sqrt(a * a + b * b)
    sigma_c = float(np.std(chroma_raw / 100.0))
    flat = np.sort(lum.ravel() / 100.0)
    n = max(1, int(round(flat.size * 0.01)))
    con_l = float(flat[-n:].mean() - flat[:n].mean())
    denom = np.sqrt(chroma_raw**2 + lum**2)
    sat = np.divide(chroma_raw, denom, out=np.zeros_like(denom), where=denom > 0)
    mu_s = float(sat.mean())
    c1, c2, c3 = UCIQE_C
    return c1 * sigma_c + c2 * con_l + c3 * mu_s


def _trimmed_stats(values: np.ndarray) -> tuple[float, float]:
    """Alpha-trimmed mean and the spread about it (the paper's mu_alpha and sigma^2_alpha)."""
    flat = np.sort(values.ravel())
    cut = int(np.floor(UICM_TRIM * flat.size))
    kept = flat[cut:flat.size - cut] if flat.size > 2 * cut else flat
    mu = float(kept.mean())
    var = float(np.mean((flat - mu) ** 2))
    return mu, var


def uicm(image: np.ndarray) -> float:
    """Colourfulness: ``-0.0268 sqrt(mu_RG^2 + mu_YB^2) + 0.1586 sqrt(s2_RG + s2_YB)`` with RG = R-G,
    YB = (R+G)/2 - B and alpha-trimmed statistics."""
    img = image.astype(np.float64)
    b, g, r = img[..., 0], img[..., 1], img[..., 2]
    mu_rg, var_rg = _trimmed_stats(r - g)
    mu_yb, var_yb = _trimmed_stats((r + g) / 2.0 - b)
    return -0.0268 * np.sqrt(mu_rg**2 + mu_yb**2) + 0.1586 * np.sqrt(var_rg + var_yb)


def _blocks(channel: np.ndarray) -> np.ndarray:
    """(k1*k2, B*B) blocks of side UIQM_BLOCK, the image cropped to whole blocks."""
    s = UIQM_BLOCK
    h = channel.shape[0] // s * s
    w = channel.shape[1] // s * s
    c = channel[:h, :w]
    return c.reshape(h // s, s, w // s, s).swapaxes(1, 2).reshape(-1, s * s)


def _eme(channel: np.ndarray) -> float:
    """Measure of enhancement: ``2/(k1 k2) sum log(max/min)`` over blocks (blocks with a zero skipped)."""
    blocks = _blocks(channel)
    hi = blocks.max(axis=1)
    lo = blocks.min(axis=1)
    ok = (lo > 0) & (hi > 0)
    if not np.any(ok):
        return 0.0
    return float(2.0 / blocks.shape[0] * np.sum(np.log(hi[ok] / lo[ok])))


def uism(image: np.ndarray) -> float:
    """Sharpness: per channel the Sobel edge magnitude times the channel, scored by EME, weighted
    0.299 R + 0.587 G + 0.114 B."""
    img = image.astype(np.float64)
    weights = (0.114, 0.587, 0.299)  # B, G, R
    total = 0.0
    for c, lam in enumerate(weights):
        ch = img[..., c]
        gx = cv2.Sobel(ch, cv2.CV_64F, 1, 0, ksize=3)
        gy = cv2.Sobel(ch, cv2.CV_64F, 0, 1, ksize=3)
        edges = np.sqrt(gx * gx + gy * gy)
        edges = edges / edges.max() if edges.max() > 0 else edges
        total += lam * _eme(edges * ch)
    return total


def uiconm(image: np.ndarray) -> float:
    """Contrast: the logAMEE of the intensity with PLIP arithmetic,
    ``1/(k1 k2) sum r log r`` where ``r = (max (-) min) / (max (+) min)`` per block, (-)/(+) the PLIP operations."""
    gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY).astype(np.float64)
    blocks = _blocks(gray)
    hi = blocks.max(axis=1)
    lo = blocks.min(axis=1)
    g = PLIP_GAMMA
    plip_minus = g * (hi - lo) / (g - lo)
    plip_plus = hi + lo - hi * lo / g
    ratio = np.divide(plip_minus, plip_plus, out=np.zeros_like(plip_plus), where=plip_plus > 0)
    ok = ratio > 0
    terms = np.zeros_like(ratio)
    terms[ok] = ratio[ok] * np.log(ratio[ok])
    # The paper's sum is negative (r < 1); its magnitude grows with contrast, so report the absolute value.
    return float(abs(terms.sum() / blocks.shape[0]))


def uiqm(image: np.ndarray) -> float:
    """Underwater image quality measure (higher: more colourful, sharper, more contrast)."""
    c1, c2, c3 = UIQM_C
    return c1 * uicm(image) + c2 * uism(image) + c3 * uiconm(image)
