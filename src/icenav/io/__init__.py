"""Inputs and outputs: gamepad, OpenIGTLink."""
