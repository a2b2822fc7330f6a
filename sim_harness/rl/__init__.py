"""DQN training and evaluation for quadnav: replay, schedules, agent, training loop, evaluation."""

__all__: list[str] = []
