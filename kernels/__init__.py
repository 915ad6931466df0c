"""Warp kernels of tdcr-warp. Imported as ``tdcr_warp.kernels``; imports only warp and siblings."""
