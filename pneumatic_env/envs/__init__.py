"""Gymnasium environments of the actuator (single and native vector)."""
