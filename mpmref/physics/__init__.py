"""Backend-neutral physics: interpolation kernels, materials and boundary projection."""
