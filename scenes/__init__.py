"""Test objects and scenes: the paper's eight objects, surface sampling, tabletop scenes."""
