"""Policy learners: SAC on the platform's envs, trained from and into MCAP episode datasets."""
