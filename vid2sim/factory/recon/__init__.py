"""Recon stage: geometry-consistent Gaussian-splat training (losses, densification, depth priors)."""
