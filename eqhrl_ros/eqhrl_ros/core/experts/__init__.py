"""Whoever answers a request: built-in controllers, an exported policy, a simulated person, imperfect
experts for studies, a person's commands (teleop), and the factory above them. Imports the wings below."""
