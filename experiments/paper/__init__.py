"""Reproductions of the seed paper's results (``make paper``): one script per figure."""
