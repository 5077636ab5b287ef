"""Monte Carlo campaigns (docs/design.md section 11): ``hil campaign``."""
