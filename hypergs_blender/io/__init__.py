"""Input and output: frames from videos and image sequences (`frames`), single images (`images`),
and the Gaussian video formats (`clips`: .hgs, .npz, .usd)."""
