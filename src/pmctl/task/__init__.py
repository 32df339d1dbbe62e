"""Task: jobs and their interpretation (LinuxCNC's task level). G-code and CL-data readers, the job
model and the look-ahead planner that turns a job into timed samples."""
