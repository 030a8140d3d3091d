"""The `cloud2cnc` command line (`cloud2cnc.cli`): it sits above the API (`service`) and the worker (`worker`)."""
