//! The machine's adapters as the runtime sees them.

mod common;

#[test]
fn at_least_one_adapter_is_listed_with_its_type_and_backend() {
    let Some(adapters) =
        common::require_gpu("at_least_one_adapter_is_listed_with_its_type_and_backend")
    else {
        return;
    };
    assert!(!adapters.is_empty());
    for a in &adapters {
        assert!(!a.name.is_empty());
        assert!(
            [
                "discrete GPU",
                "integrated GPU",
                "virtual GPU",
                "CPU (software)",
                "other"
            ]
            .contains(&a.device_type),
            "{a:?}"
        );
        assert!(!a.backend.is_empty());
    }
}
