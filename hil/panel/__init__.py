"""The front panel: a local web page over the rig service (docs/panel.md)."""
