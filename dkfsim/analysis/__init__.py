"""Analysis: functions of a run's arrays -- named metrics, intervals over runs, the paper's delay bound."""
