"""What depotbench ships beside its code, found through ``importlib.resources``: the
YOLOX-nano detector (with its licence), the cats' fur photograph (CC0, with its
provenance), example sweep specs and gate files, and example external trackers."""
