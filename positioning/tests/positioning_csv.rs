//! The positioning dataset CSV contract (`docs/datasets.md`).

use positioning::axis_model::Direction;
use positioning::positioning_data::PositioningData;

#[test]
fn full_example_with_environment_and_metadata() {
    let text = "# axis: X\n# alpha_um_per_m_k: 11.7\n# operator: someone\n\
        cycle,direction,index,target_mm,deviation_um,time_s,air_c,material_c\n\
        1,+,1,0.000,0.41,0.0,20.112,20.304\n\
        1,+,2,25.312,1.02,9.8,20.113,20.306\n";
    let d = PositioningData::from_csv_str(text).unwrap();
    assert_eq!(d.axis.as_deref(), Some("X"));
    assert!(d.material_compensation);
    assert!(d.has_times);
    assert_eq!(d.metadata["operator"], "someone");
    let r = &d.readings[1];
    assert_eq!((r.cycle, r.direction, r.index), (1, Direction::Up, 2));
    assert_eq!((r.target_mm, r.deviation_um, r.time_s), (25.312, 1.02, 9.8));
    assert_eq!((r.air_c, r.material_c), (Some(20.113), Some(20.306)));
}

#[test]
fn round_trip_through_csv() {
    let text = "# axis: Z\n# material_compensation: off\n\
        cycle,direction,index,target_mm,deviation_um,time_s,air_c,material_c\n\
        1,+,1,0,0.5,0,20.1,20.3\n1,-,1,0,0.25,5,20.1,20.4\n";
    let d = PositioningData::from_csv_str(text).unwrap();
    let back = PositioningData::from_csv_str(&d.to_csv_string()).unwrap();
    assert_eq!(back.readings, d.readings);
    assert!(!back.material_compensation);
}

fn err(text: &str) -> String {
    PositioningData::from_csv_str(text).unwrap_err().to_string()
}

#[test]
fn clear_errors() {
    assert!(
        err("").contains("header") || err("").contains("no readings"),
        "{}",
        err("")
    );
    assert!(err("cycle,direction,index,target_mm,deviation_um\n").contains("no readings"));
    let e = err("cycle,direction,index,target_mm\n1,+,1,0\n");
    assert!(e.contains("deviation_um"), "{e}");
    let e = err("cycle,direction,index,target_mm,deviation_um\n1,+,1,0,1\n0,+,2,5,1\n");
    assert!(e.contains("line 3") && e.contains("cycle"), "{e}");
    let e = err("cycle,direction,index,target_mm,deviation_um\n1,+,1,0,1\n1,+,1,0,2\n");
    assert!(e.contains("twice"), "{e}");
    let e = err("cycle,direction,index,target_mm,deviation_um\n1,+,1,0,1\n2,+,1,5,2\n");
    assert!(e.contains("target 1"), "{e}");
    let e =
        err("# alpha_um_per_m_k: steel\ncycle,direction,index,target_mm,deviation_um\n1,+,1,0,1\n");
    assert!(e.contains("alpha_um_per_m_k"), "{e}");
    let e = err("cycle,direction,index,target_mm,deviation_um,time_s\n1,+,1,0,1,later\n");
    assert!(e.contains("line 2") && e.contains("time_s"), "{e}");
    let e = err("cycle,direction,index,target_mm,deviation_um\n1,+,1,0,inf\n");
    assert!(e.contains("finite"), "{e}");
    let e = err("cycle,direction,index,target_mm,deviation_um\n1,+,1\n");
    assert!(e.contains("line 2") && e.contains("missing field"), "{e}");
}

#[test]
fn comment_lines_count_in_line_numbers() {
    let e =
        err("# a\n# b\ncycle,direction,index,target_mm,deviation_um\n1,+,1,0,1\n# c\n1,x,2,5,1\n");
    assert!(e.contains("line 6"), "{e}");
}

#[test]
fn a_rotary_run_keeps_its_unit_lines_when_written() {
    let text = "# axis: C\n# target_unit: deg\n# deviation_unit: mdeg\n\
        cycle,direction,index,target_mm,deviation_um\n1,+,1,0,1.5\n1,-,1,0,2.5\n1,+,2,90,3\n1,-,2,90,4\n";
    let d = PositioningData::from_csv_str(text).unwrap();
    let out = d.to_csv_string();
    assert!(
        out.contains("# target_unit: deg\n# deviation_unit: mdeg\n"),
        "{out}"
    );
    let back = PositioningData::from_csv_str(&out).unwrap();
    assert_eq!(back.units(), d.units());
    // A linear run writes no unit lines.
    let lin = text.replace("# target_unit: deg\n# deviation_unit: mdeg\n", "");
    assert!(
        !PositioningData::from_csv_str(&lin)
            .unwrap()
            .to_csv_string()
            .contains("_unit")
    );
}
