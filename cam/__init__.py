"""cloud2cnc geometry core: arrays in, arrays or small frozen records out."""
