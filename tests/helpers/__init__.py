"""Shared builders of test data: rendered boards, simulated sessions and mocap takes."""
