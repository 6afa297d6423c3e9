"""stdm-drake: collect UR-10 data in Drake, learn state-transition dynamics models with
derivative learning (Kim, Lee & Ryu, IEEE Access 2022), and use them in Drake diagrams."""
import os

# A remote Drake package must fail at once (offline machines); local Meshcat keeps working.
os.environ.setdefault("DRAKE_ALLOW_NETWORK", "meshcat")

__version__ = "0.1.0"
