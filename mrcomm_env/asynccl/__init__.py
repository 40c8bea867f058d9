"""AsyncCL-v0: asynchronous multi-centralized cooperative localization (Nerurkar & Roumeliotis, paper 000)."""
