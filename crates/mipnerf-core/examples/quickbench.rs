fn main() {
    use mipnerf_core::{
        bench,
        model::{ModelConfig, Preset},
    };
    let which = std::env::args().nth(1).unwrap_or_default();
    if which == "small" || which.is_empty() {
        let small = ModelConfig {
            net_depth: 4,
            net_width: 128,
            skip_layer: 2,
            net_width_condition: 64,
            num_samples: 64,
            ..ModelConfig::default()
        };
        println!("{:?}", bench::train_throughput("small", small, 1024, 1, 3));
    }
    if which == "paper" || which.is_empty() {
        println!("{:?}", bench::train_throughput("paper", Preset::Paper.config(), 1024, 1, 2));
    }
}
