//! What the scene tests share: reading a task's metric keys out of `metrics.json`.

/// The keys of a serialized task's `metrics` object, sorted.
pub fn metric_keys(task: &serde_json::Value) -> Vec<&str> {
    let mut keys: Vec<&str> = task["metrics"]
        .as_object()
        .expect("a task's metrics serialize as an object")
        .keys()
        .map(String::as_str)
        .collect();
    keys.sort_unstable();
    keys
}
