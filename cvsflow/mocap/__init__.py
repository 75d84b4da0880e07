"""Motion capture after reading: marker layouts, gap repair, rigid bodies and their resampled tables."""
