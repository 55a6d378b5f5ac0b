"""Statistics and figures of a campaign, read from run directories only.

`analyze(campaign_dir, out)` writes a tidy CSV of every evaluation, tables (IQM and mean with
stratified-bootstrap CIs, probability of improvement, Welch's t-tests against a baseline),
figures (curves with bootstrap bands, intervals, performance profiles, radar charts) and a
Markdown report. Nothing here imports training or the environments.
"""

from acl3d.analysis.report import analyze

__all__ = ["analyze"]
