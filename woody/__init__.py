"""woody: STEP tube extraction and cylinder-following reconstruction of woody structure.

- :func:`step` — STEP (Ravaglia et al. 2017): sparse 4-D point–normal Hough
  transform and open active contours, giving tuboids (ordered circles);
- :func:`follow_cylinders` — cylinder following (Méndez et al.): a
  hierarchy of branches, one cylinder each, grown from the lowest point;
- :func:`read_cloud` — NPZ (including tlssim scans), PLY, LAS and E57 readers;
- :func:`score` — scores of a cylinder list against a woody object's truth.
"""

from woody.cloud import Cloud, read_cloud
from woody.cylinders import FollowParams, FollowResult, follow_cylinders
from woody.errors import WoodyError
from woody.normals import pca_normals
from woody.scoring import score
from woody.snake import SnakeParams
from woody.step import StepResult, Tuboid, step

__all__ = ["Cloud", "FollowParams", "FollowResult", "SnakeParams", "StepResult", "Tuboid", "WoodyError",
           "follow_cylinders", "pca_normals", "read_cloud", "score", "step"]
