"""Monte Carlo campaigns (DESIGN.md section 11): ``hil campaign``."""
