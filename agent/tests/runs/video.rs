//! `million eval --video`: one GIF per task, frames rendered by a real local env server,
//! with the frame count the episode implies (one per word, one per rendered trial step, one
//! per trial outcome).

use std::path::Path;
use std::time::Instant;

use crate::common::{runtime, shipped_config};
use million::model::Model;
use million::video::{VideoOptions, record_split};
use million_env::{
    ClientConfig, EnvClient, LocalServer, LocalServerOptions, default_server_binary,
};
use tch::nn::VarStore;

fn gif_frames(path: &Path) -> (usize, u16, u16) {
    let file = std::fs::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut options = gif::DecodeOptions::new();
    options.set_color_output(gif::ColorOutput::RGBA);
    let mut decoder = options.read_info(file).unwrap();
    let (w, h) = (decoder.width(), decoder.height());
    let mut n = 0;
    while decoder.read_next_frame().unwrap().is_some() {
        n += 1;
    }
    (n, w, h)
}

#[test]
fn a_video_per_goal_with_the_expected_frames() {
    let cfg = shipped_config("quickstart.toml");
    tch::manual_seed(0);
    let vs = VarStore::new(tch::Device::Cpu);
    // Untrained weights: the test is about the video, not about what the agent learned.
    let model = Model::new(&vs.root(), &cfg.model, &cfg.popart);
    let split = cfg.eval_splits().unwrap().remove(0);
    let dir = tempfile::tempdir().unwrap();
    let rt = runtime(1);
    let opts = VideoOptions {
        every: 3,
        width: 64,
        height: 48,
        patience: 12,
        ..VideoOptions::default()
    };
    let start = Instant::now();
    let videos = rt.block_on(async {
        let binary = default_server_binary().expect("make setup installed the env server");
        let server = LocalServer::start(&binary, LocalServerOptions::default())
            .await
            .unwrap();
        let client = EnvClient::connect(server.addr(), ClientConfig::default())
            .await
            .unwrap();
        let v = record_split(&client, &split, &model, 1000, &opts, dir.path())
            .await
            .unwrap();
        drop(server);
        v
    });
    eprintln!(
        "{} videos in {:.1} s",
        videos.len(),
        start.elapsed().as_secs_f64()
    );
    let mut tasks: Vec<&str> = videos.iter().map(|v| v.task.as_str()).collect();
    tasks.sort_unstable();
    assert_eq!(
        tasks,
        ["east", "north", "south", "west"],
        "one video per goal"
    );
    for v in &videos {
        eprintln!("{v:?}");
        assert_eq!(v.trials.len(), 3, "an episode has three trials");
        assert!(
            v.words >= 2,
            "at least the first instruction's words are shown"
        );
        assert_eq!(v.frames, v.words + v.rendered + v.trials.len());
        // A trial of PointGoal (trial_len 8, every 3) renders the observations after 0, 3
        // and 6 of its agent steps, fewer when it ends early by success.
        assert!(
            v.rendered <= 3 * 3 && v.rendered >= 3,
            "{} rendered",
            v.rendered
        );
        let (n, w, h) = gif_frames(&v.path);
        assert_eq!(n, v.frames, "{}: frames in the GIF", v.path.display());
        assert_eq!(
            (u32::from(w), u32::from(h)),
            (
                million::video::canvas::MIN_WIDTH,
                48 + million::video::canvas::CAPTION_HEIGHT
            )
        );
        assert!(v.path.with_extension("png").is_file(), "a poster frame");
    }
}
