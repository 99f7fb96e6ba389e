"""mcjax-diffusion-kf: the ATC diffusion Kalman filter of Cattivelli & Sayed 2010 as an mcjax filter plugin
(registered under the entry-point group ``mcjax.filters`` as ``diffusion_kf``)."""

from .diffusion import DIFFUSION_KF, incremental_update, neighbour_contributions, step

__all__ = ["DIFFUSION_KF", "incremental_update", "neighbour_contributions", "step"]
