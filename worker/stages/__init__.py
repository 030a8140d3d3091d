"""Stage implementations: load artifacts, call `cam`, write artifacts. One module per stage."""
